//! No import circle between the source files of any crate of the repository.
//!
//! Every crate's `src/` is read as text: each path that starts with `crate::`, `super::` or
//! `self::` (in `use` lines, grouped `use a::{b, c::d}` included, and written out in code) is
//! resolved to the file that defines the module it names (the longest prefix of the path that
//! is a file: `src/a/b.rs` or `src/a/b/mod.rs`), and gives an arrow from the file it stands in
//! to that file. Comments are skipped; `super::` inside an inline `mod … { }` counts the inline
//! module. The crate root (`lib.rs`, `main.rs`) only declares and re-exports its modules: its
//! own arrows are not counted. A strongly connected set of two or more files is a circle; the
//! test fails naming each circle's arrows and the paths behind them.
//!
//! Between crates: the product's crates never depend on `crokf-verify`
//! ([`the_product_does_not_import_verify`]), and the compiler never depends on the replay tool
//! `crokf-run` or its viewer `crokf-viewer`, directly or through another crate of the
//! repository ([`the_compiler_does_not_depend_on_the_replay_tool`]).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The repository root (the parent of this crate's folder).
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the tests crate has a parent folder")
        .to_path_buf()
}

/// Every folder below `root` (two levels deep) that has a `Cargo.toml` and a `src/`.
fn crates(root: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut visit = |dir: &Path| {
        if dir.join("Cargo.toml").is_file() && dir.join("src").is_dir() {
            out.push(dir.to_path_buf());
        }
    };
    for entry in std::fs::read_dir(root)
        .expect("read the repository root")
        .flatten()
    {
        let dir = entry.path();
        let name = entry.file_name();
        if !dir.is_dir() || name == "target" || name.to_string_lossy().starts_with('.') {
            continue;
        }
        visit(&dir);
        if let Ok(inner) = std::fs::read_dir(&dir) {
            for e in inner.flatten() {
                let d = e.path();
                if d.is_dir() && e.file_name() != "target" && e.file_name() != "src" {
                    visit(&d);
                }
            }
        }
    }
    out.sort();
    out
}

/// The `.rs` files below `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The module path of a file below `src` (`a/b.rs` and `a/b/mod.rs` → [a, b]; the crate root
/// and binaries under `bin/` → []), or None for a root (`lib.rs`, `main.rs`, `bin/*`).
fn module_of(src: &Path, file: &Path) -> Option<Vec<String>> {
    let rel = file.strip_prefix(src).ok()?;
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    if parts.first().is_some_and(|p| p == "bin") {
        return None;
    }
    let last = parts.pop()?;
    let stem = last.trim_end_matches(".rs");
    if parts.is_empty() && (stem == "lib" || stem == "main") {
        return None;
    }
    if stem != "mod" {
        parts.push(stem.to_owned());
    }
    Some(parts)
}

/// The text of a line without its `//` comment (a `//` inside a string literal ends the line
/// early, which only hides paths, never invents one).
fn code_of(line: &str) -> &str {
    let mut in_string = false;
    let bytes = line.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'\\' if in_string => i += 1,
            b'"' => in_string = !in_string,
            b'/' if !in_string && bytes.get(i + 1) == Some(&b'/') => return &line[..i],
            _ => {}
        }
        i += 1;
    }
    line
}

/// Expands a `use` tree (`a::{b, c::{d, self}}`) into full paths.
fn expand(tree: &str, prefix: &str, out: &mut Vec<String>) {
    let tree = tree.trim();
    if tree.is_empty() {
        return;
    }
    if let Some(open) = tree.find('{') {
        let head = tree[..open].trim().trim_end_matches("::");
        let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
        let base = join(prefix, head);
        let mut depth = 0;
        let mut start = 0;
        for (i, ch) in inner.char_indices() {
            match ch {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    expand(&inner[start..i], &base, out);
                    start = i + 1;
                }
                _ => {}
            }
        }
        expand(&inner[start..], &base, out);
    } else {
        let item = tree.split(" as ").next().unwrap_or(tree).trim();
        out.push(if item == "self" {
            prefix.to_owned()
        } else {
            join(prefix, item)
        });
    }
}

fn join(prefix: &str, tail: &str) -> String {
    match (prefix.is_empty(), tail.is_empty()) {
        (true, _) => tail.to_owned(),
        (_, true) => prefix.to_owned(),
        _ => format!("{prefix}::{tail}"),
    }
}

/// The paths a file names: `(path, inline module depth)` per `crate::`/`super::`/`self::` path.
fn paths_of(text: &str) -> Vec<(String, usize)> {
    let mut out = Vec::new();
    // Inline modules: the brace depth at which each one opened.
    let mut inline: Vec<i64> = Vec::new();
    let mut depth: i64 = 0;
    let mut pending_use = String::new();
    for raw in text.lines() {
        let line = code_of(raw);
        let trimmed = line.trim();
        let opens_module = {
            let t = trimmed
                .trim_start_matches("pub(crate) ")
                .trim_start_matches("pub ");
            t.starts_with("mod ") && t.ends_with('{')
        };
        // A `use` statement, possibly over several lines.
        let in_use = !pending_use.is_empty();
        let starts_use = {
            let t = trimmed
                .trim_start_matches("pub(crate) ")
                .trim_start_matches("pub ");
            t.starts_with("use ")
        };
        if in_use || starts_use {
            pending_use.push_str(line);
            pending_use.push(' ');
            if trimmed.ends_with(';') || !trimmed.ends_with(|c: char| "{},:".contains(c)) {
                let statement = pending_use.trim().trim_end_matches(';');
                let tree = statement[statement.find("use ").map_or(0, |i| i + 4)..].trim();
                // Text that merely starts with "use " (in a string, say) is no use tree.
                let is_tree = tree
                    .chars()
                    .all(|c| c.is_alphanumeric() || c.is_whitespace() || "_:{},*".contains(c));
                let mut paths = Vec::new();
                if is_tree {
                    expand(tree, "", &mut paths);
                }
                for p in paths {
                    if ["crate::", "super::", "self::"]
                        .iter()
                        .any(|s| p.starts_with(s))
                    {
                        out.push((p, inline.len()));
                    }
                }
                pending_use.clear();
            }
        } else {
            // Paths written out in code.
            for start in ["crate::", "super::", "self::"] {
                let mut from = 0;
                while let Some(i) = line[from..].find(start) {
                    let at = from + i;
                    let before = line[..at].chars().next_back();
                    from = at + start.len();
                    if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
                        continue;
                    }
                    let path: String = line[at..]
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                        .collect();
                    out.push((path.trim_end_matches(':').to_owned(), inline.len()));
                }
            }
        }
        for ch in line.chars() {
            match ch {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if inline.last() == Some(&depth) {
                        inline.pop();
                    }
                }
                _ => {}
            }
        }
        if opens_module {
            inline.push(depth - 1);
        }
    }
    out
}

/// The file that defines the module named by the longest prefix of `path` (absolute segments).
fn resolve(modules: &BTreeMap<Vec<String>, PathBuf>, path: &[String]) -> Option<PathBuf> {
    (1..=path.len())
        .rev()
        .find_map(|n| modules.get(&path[..n]).cloned())
}

/// A crate's arrows: file → (file → the paths behind the arrow).
type Arrows = BTreeMap<PathBuf, BTreeMap<PathBuf, BTreeSet<String>>>;

/// The arrows between the files of the crate at `dir`.
fn arrows(dir: &Path) -> Arrows {
    let src = dir.join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let modules: BTreeMap<Vec<String>, PathBuf> = files
        .iter()
        .filter_map(|f| module_of(&src, f).map(|m| (m, f.clone())))
        .filter(|(m, _)| !m.is_empty())
        .collect();
    let mut out = Arrows::new();
    for file in &files {
        let Some(here) = module_of(&src, file) else {
            continue;
        };
        let text = std::fs::read_to_string(file).expect("read a source file");
        for (path, inline) in paths_of(&text) {
            let mut segments: Vec<&str> = path.split("::").filter(|s| !s.is_empty()).collect();
            let absolute: Vec<String> = match segments.first().copied() {
                Some("crate") => segments.drain(1..).map(str::to_owned).collect(),
                Some("self") => here
                    .iter()
                    .cloned()
                    .chain(segments.drain(1..).map(str::to_owned))
                    .collect(),
                Some("super") => {
                    let ups = segments.iter().take_while(|s| **s == "super").count();
                    // Inside an inline module the first `super`s climb out of it.
                    let climb = ups.saturating_sub(inline);
                    if climb > here.len() {
                        continue;
                    }
                    here[..here.len() - climb]
                        .iter()
                        .cloned()
                        .chain(segments.drain(ups..).map(str::to_owned))
                        .collect()
                }
                _ => continue,
            };
            if let Some(target) = resolve(&modules, &absolute) {
                if &target != file {
                    out.entry(file.clone())
                        .or_default()
                        .entry(target)
                        .or_default()
                        .insert(path.clone());
                }
            }
        }
    }
    out
}

/// Strongly connected sets of two or more files (Tarjan).
fn circles(arrows: &Arrows) -> Vec<Vec<PathBuf>> {
    struct Walk<'a> {
        arrows: &'a Arrows,
        index: BTreeMap<&'a PathBuf, usize>,
        low: BTreeMap<&'a PathBuf, usize>,
        stack: Vec<&'a PathBuf>,
        on_stack: BTreeSet<&'a PathBuf>,
        out: Vec<Vec<PathBuf>>,
    }
    impl<'a> Walk<'a> {
        fn visit(&mut self, v: &'a PathBuf) {
            let n = self.index.len();
            self.index.insert(v, n);
            self.low.insert(v, n);
            self.stack.push(v);
            self.on_stack.insert(v);
            if let Some(targets) = self.arrows.get(v) {
                for w in targets.keys() {
                    if !self.index.contains_key(w) {
                        self.visit(w);
                        let low = self.low[v].min(self.low[w]);
                        self.low.insert(v, low);
                    } else if self.on_stack.contains(w) {
                        let low = self.low[v].min(self.index[w]);
                        self.low.insert(v, low);
                    }
                }
            }
            if self.low[v] == self.index[v] {
                let mut set = Vec::new();
                while let Some(w) = self.stack.pop() {
                    self.on_stack.remove(w);
                    set.push(w.clone());
                    if w == v {
                        break;
                    }
                }
                if set.len() > 1 {
                    set.sort();
                    self.out.push(set);
                }
            }
        }
    }
    let mut walk = Walk {
        arrows,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in arrows.keys() {
        if !walk.index.contains_key(v) {
            walk.visit(v);
        }
    }
    walk.out
}

#[test]
fn no_crate_has_an_import_circle() {
    let root = root();
    let crates = crates(&root);
    assert!(
        crates.iter().any(|c| c.ends_with("compiler")) && crates.len() >= 8,
        "the walk found too few crates: {crates:?}"
    );
    let mut report = Vec::new();
    for dir in &crates {
        let arrows = arrows(dir);
        for set in circles(&arrows) {
            let name = |p: &PathBuf| p.strip_prefix(&root).unwrap_or(p).display().to_string();
            let mut lines = vec![format!("circle of {} files in {}:", set.len(), name(dir))];
            for a in &set {
                for (b, paths) in arrows.get(a).into_iter().flatten() {
                    if set.contains(b) {
                        let paths: Vec<&str> = paths.iter().map(String::as_str).collect();
                        lines.push(format!(
                            "  {} -> {}: {}",
                            name(a),
                            name(b),
                            paths.join(", ")
                        ));
                    }
                }
            }
            report.push(lines.join("\n"));
        }
    }
    assert!(report.is_empty(), "import circles:\n{}", report.join("\n"));
}

/// The compiler's algorithms (`compiler/src/algorithms/`: Krylov–Schur, POD, NNLS, the Kalman
/// filter's design) know no physics: no file of theirs imports a module of the crate outside
/// them, so a reductor wires them and they never reach up into meshes, scenes or models.
#[test]
fn the_compilers_algorithms_import_nothing_else_of_the_crate() {
    let root = root();
    let src = root.join("compiler").join("src");
    let inside = |p: &Path| p.starts_with(src.join("algorithms")) || p == src.join("algorithms.rs");
    let arrows = arrows(&root.join("compiler"));
    assert!(
        arrows.keys().filter(|f| inside(f)).count() >= 5,
        "the walk found too few files of the algorithms importing each other"
    );
    let mut found = Vec::new();
    for (from, targets) in &arrows {
        if !inside(from) {
            continue;
        }
        for (to, paths) in targets {
            if !inside(to) {
                let name = |p: &Path| p.strip_prefix(&root).unwrap_or(p).display().to_string();
                let paths: Vec<&str> = paths.iter().map(String::as_str).collect();
                found.push(format!(
                    "{} -> {}: {}",
                    name(from),
                    name(to),
                    paths.join(", ")
                ));
            }
        }
    }
    assert!(
        found.is_empty(),
        "an algorithm imports the rest of the compiler:\n{}",
        found.join("\n")
    );
}

/// The compiler's scene (`compiler/src/scene.rs` and `compiler/src/scene/`: the scene file's
/// schema and its checks) is read and checked before any tier is built: no file of it imports
/// the co-rotational tier's modules (`compiler/src/nonlinear.rs`, `compiler/src/nonlinear/`),
/// which are built on the scene. What its checks need of the training's size is the scene's
/// own.
#[test]
fn the_compilers_scene_imports_nothing_of_the_tier() {
    let root = root();
    let src = root.join("compiler").join("src");
    let within =
        |p: &Path, name: &str| p.starts_with(src.join(name)) || p == src.join(format!("{name}.rs"));
    let arrows = arrows(&root.join("compiler"));
    assert!(
        arrows.keys().filter(|f| within(f, "scene")).count() >= 2
            && arrows
                .values()
                .flat_map(|t| t.keys())
                .any(|f| within(f, "nonlinear")),
        "the walk found too few arrows from the scene or to the tier"
    );
    let mut found = Vec::new();
    for (from, targets) in &arrows {
        if !within(from, "scene") {
            continue;
        }
        for (to, paths) in targets {
            if within(to, "nonlinear") {
                let name = |p: &Path| p.strip_prefix(&root).unwrap_or(p).display().to_string();
                let paths: Vec<&str> = paths.iter().map(String::as_str).collect();
                found.push(format!(
                    "{} -> {}: {}",
                    name(from),
                    name(to),
                    paths.join(", ")
                ));
            }
        }
    }
    assert!(
        found.is_empty(),
        "the scene imports the co-rotational tier:\n{}",
        found.join("\n")
    );
}

/// The product (the compiler, the runtime, crokf-run, the viewer, the shared formats and kernel,
/// the Python package) never depends on the verification crate: no `crokf-verify` dependency in
/// its `Cargo.toml`, no `crokf_verify` path in its code (comments aside).
#[test]
fn the_product_does_not_import_verify() {
    let root = root();
    let mut found = Vec::new();
    for name in [
        "compiler", "runtime", "run", "viewer", "formats", "kernel", "python",
    ] {
        let dir = root.join(name);
        let manifest = std::fs::read_to_string(dir.join("Cargo.toml")).expect("read a manifest");
        for (i, line) in manifest.lines().enumerate() {
            if line.trim_start().starts_with("crokf-verify") {
                found.push(format!("{name}/Cargo.toml:{}: {line}", i + 1));
            }
        }
        let mut files = Vec::new();
        rust_files(&dir.join("src"), &mut files);
        files.sort();
        for file in files {
            let text = std::fs::read_to_string(&file).expect("read a source file");
            for (i, line) in text.lines().enumerate() {
                if code_of(line).contains("crokf_verify") {
                    let shown = file
                        .strip_prefix(&root)
                        .unwrap_or(&file)
                        .display()
                        .to_string();
                    found.push(format!("{shown}:{}: {}", i + 1, line.trim()));
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "the product imports crokf-verify:\n{}",
        found.join("\n")
    );
}

/// The normal dependencies a manifest names (`[dependencies]`, `[target.….dependencies]` and
/// `[dependencies.NAME]` sections; not dev- or build-dependencies), each with its `path = "…"`
/// if it gives one.
fn normal_dependencies(manifest: &str) -> Vec<(String, Option<String>)> {
    let mut out = Vec::new();
    let mut in_section = false;
    for line in manifest.lines() {
        let line = code_of_toml(line).trim();
        if line.starts_with('[') {
            let header = line.trim_matches(|c| c == '[' || c == ']').trim();
            in_section = header == "dependencies"
                || (header.starts_with("target.") && header.ends_with(".dependencies"));
            if let Some(name) = header.strip_prefix("dependencies.") {
                out.push((name.trim().to_owned(), None));
            }
            continue;
        }
        if !in_section || line.is_empty() {
            continue;
        }
        let name: String = line
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '-' || *c == '_')
            .collect();
        if name.is_empty() {
            continue;
        }
        let path = line[name.len()..].match_indices("path").find_map(|(i, _)| {
            let rest = &line[name.len() + i + 4..];
            let rest = rest.trim_start().strip_prefix('=')?.trim_start();
            let rest = rest.strip_prefix('"')?;
            Some(rest[..rest.find('"')?].to_owned())
        });
        out.push((name, path));
    }
    out
}

/// A manifest line without its `#` comment (a `#` inside a string ends it early).
fn code_of_toml(line: &str) -> &str {
    line.find('#').map_or(line, |i| &line[..i])
}

/// The repository's crates by package name: `[workspace.dependencies]` of the root manifest
/// (`crokf-x = { path = "x" }`) → folder.
fn workspace_crates(root: &Path) -> BTreeMap<String, PathBuf> {
    let manifest =
        std::fs::read_to_string(root.join("Cargo.toml")).expect("read the root manifest");
    let mut out = BTreeMap::new();
    let mut in_section = false;
    for line in manifest.lines() {
        let line = code_of_toml(line).trim();
        if line.starts_with('[') {
            in_section = line == "[workspace.dependencies]";
            continue;
        }
        if !in_section {
            continue;
        }
        if let Some((name, Some(path))) = normal_dependencies(&format!("[dependencies]\n{line}"))
            .into_iter()
            .next()
        {
            out.insert(name, root.join(path));
        }
    }
    out
}

/// The repository crates `dir`'s crate depends on through normal dependencies, directly or
/// through other repository crates: package name → the chain that leads to it.
fn normal_closure(root: &Path, dir: &Path) -> BTreeMap<String, Vec<String>> {
    let members = workspace_crates(root);
    let mut found: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let mut todo = vec![(dir.to_path_buf(), Vec::<String>::new())];
    while let Some((dir, chain)) = todo.pop() {
        let manifest = std::fs::read_to_string(dir.join("Cargo.toml")).expect("read a manifest");
        for (name, path) in normal_dependencies(&manifest) {
            let folder = match path {
                Some(p) => Some(dir.join(p)),
                None => members.get(&name).cloned(),
            };
            let Some(folder) = folder else {
                continue; // a crate from the registry
            };
            if found.contains_key(&name) {
                continue;
            }
            let mut to = chain.clone();
            to.push(name.clone());
            found.insert(name, to.clone());
            todo.push((folder, to));
        }
    }
    found
}

/// The compiler (a library the Python package and the verification crate link) does not pull
/// in the replay tool and its HTTP viewer: neither `crokf-run` nor `crokf-viewer` is among its
/// normal dependencies, direct or through another crate of the repository (the recording's
/// CSV readers of `crokf-compile identify` are `crokf_runtime::table`).
#[test]
fn the_compiler_does_not_depend_on_the_replay_tool() {
    let root = root();
    let closure = normal_closure(&root, &root.join("compiler"));
    assert!(
        closure.contains_key("crokf-runtime") && closure.contains_key("crokf-formats"),
        "the walk missed the compiler's own dependencies: {closure:?}"
    );
    let found: Vec<String> = ["crokf-run", "crokf-viewer"]
        .iter()
        .filter_map(|name| closure.get(*name))
        .map(|chain| format!("crokf-compile -> {}", chain.join(" -> ")))
        .collect();
    assert!(
        found.is_empty(),
        "crokf-compile depends on the replay tool:\n{}",
        found.join("\n")
    );
    // The walk sees through a crate: crokf-run reaches the viewer.
    let run = normal_closure(&root, &root.join("run"));
    assert_eq!(
        run.get("crokf-viewer").map(Vec::as_slice),
        Some(&["crokf-viewer".to_owned()][..])
    );
}

/// The manifest reader: sections, inline tables, paths, comments.
#[test]
fn the_manifest_reader_keeps_normal_dependencies_only() {
    let text = "[package]\nname = \"x\"\n[dependencies]\n# crokf-run.workspace = true\n\
                crokf-runtime = { workspace = true, features = [\"table\"] }\n\
                local = { path = \"../local\" } # a comment\n\
                [target.'cfg(unix)'.dependencies]\nlibc = \"0.2\"\n\
                [dev-dependencies]\ncrokf-run.workspace = true\n\
                [build-dependencies]\nsyn = \"3\"\n[dependencies.crokf-viewer]\nworkspace = true\n";
    assert_eq!(
        normal_dependencies(text),
        [
            ("crokf-runtime".to_owned(), None),
            ("local".to_owned(), Some("../local".to_owned())),
            ("libc".to_owned(), None),
            ("crokf-viewer".to_owned(), None),
        ]
    );
}

/// The walk itself: grouped `use` trees, `super` out of an inline module, a circle found.
#[test]
fn the_walk_reads_grouped_uses_and_finds_a_circle() {
    let mut paths = Vec::new();
    expand("crate::a::{self, b::{C, d}, e as f}", "", &mut paths);
    assert_eq!(
        paths,
        [
            "crate::a",
            "crate::a::b::C",
            "crate::a::b::d",
            "crate::a::e"
        ]
    );
    let text = "use super::x::Y;\nfn f() { crate::b::g(); } // crate::c::h\n\
                #[cfg(test)]\nmod tests {\n    use super::*;\n}\n";
    let found = paths_of(text);
    assert_eq!(
        found,
        [
            ("super::x::Y".to_owned(), 0),
            ("crate::b::g".to_owned(), 0),
            ("super::*".to_owned(), 1)
        ]
    );
    let (a, b, c) = (
        PathBuf::from("a.rs"),
        PathBuf::from("b.rs"),
        PathBuf::from("c.rs"),
    );
    let mut arrows = Arrows::new();
    for (from, to) in [(&a, &b), (&b, &c), (&c, &a)] {
        arrows
            .entry(from.clone())
            .or_default()
            .entry(to.clone())
            .or_default()
            .insert("x".into());
    }
    assert_eq!(
        circles(&arrows),
        vec![vec![a.clone(), b.clone(), c.clone()]]
    );
    arrows.get_mut(&c).map(|t| t.remove(&a));
    assert!(circles(&arrows).is_empty());
}
