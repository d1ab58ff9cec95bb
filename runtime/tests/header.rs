//! `runtime/include/crokf.h` declares exactly the functions the cdylib exports (both
//! directions), read from the library's dynamic symbol table with `nm -D` (binutils, installed
//! with the C compiler the C example test needs).

mod common;
use common::find_cdylib;
use std::collections::BTreeSet;
use std::process::Command;

/// Names `crokf_…` directly followed by `(` outside comments: the declared functions.
fn declared_functions(header: &str) -> BTreeSet<String> {
    let mut code = String::new();
    let mut rest = header;
    while let Some(i) = rest.find("/*") {
        code.push_str(&rest[..i]);
        rest = rest[i..].find("*/").map_or("", |j| &rest[i + j + 2..]);
    }
    code.push_str(rest);
    let code: String = code
        .lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let mut names = BTreeSet::new();
    let bytes = code.as_bytes();
    let mut from = 0;
    while let Some(i) = code[from..].find("crokf_") {
        let start = from + i;
        let mut end = start;
        while end < bytes.len() && (bytes[end].is_ascii_alphanumeric() || bytes[end] == b'_') {
            end += 1;
        }
        let boundary =
            start == 0 || !(bytes[start - 1].is_ascii_alphanumeric() || bytes[start - 1] == b'_');
        let next = code[end..].trim_start().chars().next();
        if boundary && next == Some('(') {
            names.insert(code[start..end].to_owned());
        }
        from = end;
    }
    names
}

#[test]
fn header_matches_the_exported_symbols() {
    let header =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/include/crokf.h")).unwrap();
    let declared = declared_functions(&header);
    assert!(declared.len() >= 25, "parsed only {declared:?}");
    let lib = find_cdylib();
    let out = Command::new("nm")
        .args(["-D", "--defined-only"])
        .arg(&lib)
        .output()
        .expect("nm (binutils) runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let exported: BTreeSet<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let mut f = l.split_whitespace().rev();
            let name = f.next()?;
            let kind = f.next()?;
            (kind == "T" && name.starts_with("crokf_")).then(|| name.to_owned())
        })
        .collect();
    let undeclared: Vec<_> = exported.difference(&declared).collect();
    let missing: Vec<_> = declared.difference(&exported).collect();
    assert!(
        undeclared.is_empty() && missing.is_empty(),
        "exported but not in crokf.h: {undeclared:?}; declared but not exported: {missing:?}"
    );
}

#[test]
fn the_header_parser_sees_declarations_only() {
    let h = "/* crokf_in_comment(x) */\nint crokf_a(void);\n// crokf_line(\nvoid *crokf_b (int);\nint my_crokf_c(void);\ntypedef struct crokf_T crokf_T;";
    let names: Vec<_> = declared_functions(h).into_iter().collect();
    assert_eq!(names, ["crokf_a", "crokf_b"]);
}
