//! The runtime's public items do not change by accident: every `pub` declaration in
//! `runtime/src` (item, field, method, re-export; not `pub(crate)` or `pub(super)`) is listed,
//! with its file and its signature up to the body, in `runtime/public-api.txt`. A change to
//! that list is a change to the API: the test fails with the difference and writes the new
//! list beside the old one (`target/public-api.txt`) for the change to copy on purpose.
//!
//! The scan reads text, not Rust: it takes each line that starts (after indentation and
//! attributes) with `pub ` and joins the following lines until the signature ends (`{`, `;`,
//! or a field's or variant's `,`). Unit tests (a `#[cfg(test)] mod` at column 0, to the end of
//! the file) are not scanned.

use std::path::{Path, PathBuf};

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// One declaration's signature: from `pub ` to the first `{`, `;` or trailing `,` (at bracket
/// depth 0), whitespace collapsed.
fn signature(lines: &[&str], start: usize) -> String {
    let mut text = String::new();
    let mut depth = 0i32;
    // A re-export's braces are its list: it ends at `;`.
    let is_use = lines[start].trim_start().starts_with("pub use ");
    let mut prev = ' ';
    for line in &lines[start..] {
        let line = line.split("//").next().unwrap_or("");
        for c in line.trim().chars() {
            match c {
                // `<` opens generics after a name or `::`, not in `1 << 20`.
                '<' if !(prev.is_alphanumeric() || prev == ':' || prev == '_') => {}
                '(' | '[' | '<' => depth += 1,
                // `->` is not a closing bracket.
                '>' if prev == '-' => {}
                ')' | ']' | '>' if depth > 0 => depth -= 1,
                ';' if depth == 0 => return collapse(&text),
                '{' | ',' if depth == 0 && !is_use => return collapse(&text),
                _ => {}
            }
            text.push(c);
            prev = c;
        }
        text.push(' ');
    }
    collapse(&text)
}

fn collapse(text: &str) -> String {
    text.split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .replace("( ", "(")
        .replace(", )", ")")
        .replace(",)", ")")
        .replace(" )", ")")
}

fn public_items(root: &Path) -> String {
    let mut files = Vec::new();
    sources(&root.join("src"), &mut files);
    let mut list = String::new();
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        // A file's unit tests: `#[cfg(test)]` at column 0 on a `mod` (not one on a single item).
        let end = lines
            .windows(2)
            .position(|w| w[0] == "#[cfg(test)]" && w[1].starts_with("mod "))
            .unwrap_or(lines.len());
        let name = file
            .strip_prefix(root)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        let mut i = 0;
        while i < end {
            let trimmed = lines[i].trim_start();
            if trimmed.starts_with("pub ") {
                let item = signature(&lines, i);
                list.push_str(&format!("{name}: {item}\n"));
                if let Some(rest) = item.strip_prefix("pub enum ") {
                    let indent = indent_of(lines[i]);
                    i = variants(&lines[..end], i, indent, rest, &name, &mut list);
                    continue;
                }
            }
            i += 1;
        }
    }
    list
}

fn indent_of(line: &str) -> usize {
    line.len() - line.trim_start().len()
}

/// The variants of the public enum `name` declared at line `start` (indentation `indent`), and
/// the fields of its struct variants, listed as `enum NAME::VARIANT` and
/// `enum NAME::VARIANT.field: type`; returns the line after the enum.
fn variants(
    lines: &[&str],
    start: usize,
    indent: usize,
    name: &str,
    file: &str,
    list: &mut String,
) -> usize {
    let name = name.split(['<', ' ']).next().unwrap_or(name);
    let mut variant = String::new();
    let mut i = start + 1;
    while i < lines.len() {
        let line = lines[i];
        let trimmed = line.trim_start();
        let depth = indent_of(line);
        if trimmed.starts_with('}') && depth == indent {
            return i + 1;
        }
        // A variant starts with its capitalised name, a field of a struct variant with
        // `name:` (attribute and doc lines, and their continuations, match neither).
        let ident: String = trimmed
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        let after = &trimmed[ident.len()..];
        let is_variant = ident.starts_with(|c: char| c.is_ascii_uppercase())
            && (after.is_empty() || after.starts_with([' ', '(', ',']));
        let is_field = ident.starts_with(|c: char| c.is_ascii_lowercase() || c == '_')
            && after.starts_with(':');
        if is_variant && depth == indent + 4 {
            variant = signature(lines, i);
            list.push_str(&format!("{file}: enum {name}::{variant}\n"));
        } else if is_field && depth == indent + 8 {
            let field = signature(lines, i);
            let of = variant.split([' ', '(']).next().unwrap_or("");
            list.push_str(&format!("{file}: enum {name}::{of}.{field}\n"));
        }
        i += 1;
    }
    i
}

#[test]
fn the_public_items_are_the_committed_list() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let found = public_items(root);
    let committed = std::fs::read_to_string(root.join("public-api.txt")).unwrap_or_default();
    if found != committed {
        let new = root.join("../target/public-api.txt");
        let _ = std::fs::create_dir_all(new.parent().unwrap());
        std::fs::write(&new, &found).unwrap();
        let old: Vec<&str> = committed.lines().collect();
        let now: Vec<&str> = found.lines().collect();
        let removed: Vec<&&str> = old.iter().filter(|l| !now.contains(l)).collect();
        let added: Vec<&&str> = now.iter().filter(|l| !old.contains(l)).collect();
        panic!(
            "the runtime's public items changed.\nremoved:\n{}\nadded:\n{}\nIf on purpose: cp {} \
             runtime/public-api.txt",
            removed
                .iter()
                .map(|l| format!("  - {l}"))
                .collect::<Vec<_>>()
                .join("\n"),
            added
                .iter()
                .map(|l| format!("  + {l}"))
                .collect::<Vec<_>>()
                .join("\n"),
            new.display()
        );
    }
}

#[test]
fn the_scan_sees_items_fields_and_multi_line_signatures() {
    let text = "pub struct A {\n    pub x: f64,\n    y: u8,\n}\npub fn f(\n    a: &[f64],\n    b: \
                usize,\n) -> Result<(), E> {\n}\npub(crate) fn g() {}\npub use m::{B, C};\n";
    let lines: Vec<&str> = text.lines().collect();
    let sigs: Vec<String> = lines
        .iter()
        .enumerate()
        .filter(|(_, l)| l.trim_start().starts_with("pub "))
        .map(|(i, _)| signature(&lines, i))
        .collect();
    assert_eq!(
        sigs,
        [
            "pub struct A",
            "pub x: f64",
            "pub fn f(a: &[f64], b: usize) -> Result<(), E>",
            "pub use m::{B, C}",
        ]
    );
    let text = "pub fn h(get: impl Fn(usize) -> Option<f64>, k: u8) -> bool {\n}\n\
                pub enum E {\n    /// A.\n    A {\n        /// x.\n        x: u8,\n    },\n    \
                B(String),\n}\npub const N: usize = 2;\n";
    let lines: Vec<&str> = text.lines().collect();
    let mut list = String::new();
    assert_eq!(
        signature(&lines, 0),
        "pub fn h(get: impl Fn(usize) -> Option<f64>, k: u8) -> bool"
    );
    let after = variants(&lines, 2, 0, "E", "f.rs", &mut list);
    assert_eq!(
        list,
        "f.rs: enum E::A\nf.rs: enum E::A.x: u8\nf.rs: enum E::B(String)\n"
    );
    assert_eq!(lines[after], "pub const N: usize = 2;");
    assert_eq!(signature(&lines, after), "pub const N: usize = 2");
}
