//! The shape of the code, held by a test: modules import only the layers below them (so
//! there is no import back up and no circle), functions stay short enough to read, every
//! test file is in docs/testing.md, and every Python peer sits at `tests/peers/<test>.py`
//! beside the test that runs it. docs/architecture.md explains the layers.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// `src/`'s modules from the bottom up: each may use those before it, never one after it.
/// `gateway` is two rooms: its core (no I/O), and above it its shell (the links, the tokio
/// driver and the services).
const LAYERS: &[&[&str]] = &[
    &["time", "geometry", "svg"],
    &["calibration", "planner"],
    &["track"],
    &["control"],
    &["config"],
    &["gateway::core"],
    &["gateway::shell"],
    &["replay", "setup"],
    &["lab"],
    &["cli"],
];

/// The longest function anywhere in `src/`, and in the core and the CLI, lines.
const LONGEST: usize = 80;
const LONGEST_IN_CORE_AND_CLI: usize = 60;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let p = entry.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|e| e == "rs") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// The module a file of `src/` belongs to, as [`LAYERS`] names it.
fn module_of(file: &Path) -> String {
    let rel = file.strip_prefix(root().join("src")).unwrap();
    let parts: Vec<String> = rel.with_extension("").iter().map(|p| p.to_string_lossy().into_owned()).collect();
    match parts.as_slice() {
        [g, room, ..] if g == "gateway" && (room == "core" || room == "shell") => format!("gateway::{room}"),
        [first, ..] => first.clone(),
        [] => String::new(),
    }
}

fn layer(module: &str) -> Option<usize> {
    LAYERS.iter().position(|l| l.contains(&module))
}

/// The text with comments, strings and character literals blanked (newlines kept), so
/// that braces and paths are only the code's.
fn code_only(text: &str) -> String {
    let c: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    let blank = |ch: char| if ch == '\n' { '\n' } else { ' ' };
    while i < c.len() {
        let next = c.get(i + 1).copied();
        if c[i] == '/' && next == Some('/') {
            while i < c.len() && c[i] != '\n' {
                out.push(' ');
                i += 1;
            }
        } else if c[i] == '/' && next == Some('*') {
            let mut depth = 0;
            loop {
                if i >= c.len() {
                    break;
                }
                if c[i] == '/' && c.get(i + 1) == Some(&'*') {
                    depth += 1;
                    out.push_str("  ");
                    i += 2;
                } else if c[i] == '*' && c.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    out.push_str("  ");
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    out.push(blank(c[i]));
                    i += 1;
                }
            }
        } else if c[i] == 'r' && (next == Some('"') || next == Some('#')) && (i == 0 || !c[i - 1].is_alphanumeric()) {
            // A raw string: r"..." or r#"..."#.
            let mut j = i + 1;
            let mut hashes = 0;
            while c.get(j) == Some(&'#') {
                hashes += 1;
                j += 1;
            }
            if c.get(j) != Some(&'"') {
                out.push(c[i]);
                i += 1;
                continue;
            }
            j += 1;
            while j < c.len() && !(c[j] == '"' && (0..hashes).all(|h| c.get(j + 1 + h) == Some(&'#'))) {
                j += 1;
            }
            let end = (j + 1 + hashes).min(c.len());
            out.extend(c[i..end].iter().map(|&ch| blank(ch)));
            i = end;
        } else if c[i] == '"' {
            let mut j = i + 1;
            while j < c.len() && c[j] != '"' {
                j += if c[j] == '\\' { 2 } else { 1 };
            }
            let end = (j + 1).min(c.len());
            out.extend(c[i..end].iter().map(|&ch| blank(ch)));
            i = end;
        } else if c[i] == '\'' {
            // A character literal ('x', '\n', '\u{..}'), or a lifetime ('a), which stays.
            let end = if next == Some('\\') {
                (i + 2..c.len()).find(|&j| c[j] == '\'').map(|j| j + 1)
            } else if c.get(i + 2) == Some(&'\'') {
                Some(i + 3)
            } else {
                None
            };
            match end {
                Some(end) => {
                    out.extend(c[i..end].iter().map(|&ch| blank(ch)));
                    i = end;
                }
                None => {
                    out.push(c[i]);
                    i += 1;
                }
            }
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    out
}

/// Every function in `code` (see [`code_only`]): its name, first line and length in lines.
fn functions(code: &str) -> Vec<(String, usize, usize)> {
    let line_of: Vec<usize> = {
        let mut line = 1;
        code.chars()
            .map(|ch| {
                let l = line;
                line += usize::from(ch == '\n');
                l
            })
            .collect()
    };
    let c: Vec<char> = code.chars().collect();
    let mut out = Vec::new();
    for i in 0..c.len().saturating_sub(3) {
        let starts_word = i == 0 || !(c[i - 1].is_alphanumeric() || c[i - 1] == '_');
        if !(starts_word && c[i] == 'f' && c[i + 1] == 'n' && c[i + 2] == ' ') {
            continue;
        }
        let name: String = c[i + 3..].iter().take_while(|ch| ch.is_alphanumeric() || **ch == '_').collect();
        if name.is_empty() {
            continue; // a function pointer type, `fn(..)`
        }
        // The body: from the first `{` before any `;` to its matching `}`.
        let mut j = i + 3 + name.len();
        while j < c.len() && c[j] != '{' && c[j] != ';' {
            j += 1;
        }
        if j >= c.len() || c[j] == ';' {
            continue;
        }
        let mut depth = 0;
        let mut k = j;
        while k < c.len() {
            match c[k] {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        break;
                    }
                }
                _ => {}
            }
            k += 1;
        }
        let k = k.min(c.len() - 1);
        out.push((name, line_of[i], line_of[k] - line_of[i] + 1));
    }
    out
}

/// `crate::module` paths the code names, as [`LAYERS`] names modules.
fn imported_modules(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    for (at, _) in code.match_indices("crate::") {
        let rest = &code[at + "crate::".len()..];
        let first: String = rest.chars().take_while(|ch| ch.is_alphanumeric() || *ch == '_').collect();
        let second: String = rest[first.len()..]
            .strip_prefix("::")
            .map(|r| r.chars().take_while(|ch| ch.is_alphanumeric() || *ch == '_').collect())
            .unwrap_or_default();
        if first == "gateway" && (second == "core" || second == "shell") {
            out.push(format!("gateway::{second}"));
        } else {
            out.push(first);
        }
    }
    out
}

#[test]
fn modules_import_only_the_layers_below_them() {
    let mut wrong = Vec::new();
    let mut edges: BTreeMap<String, std::collections::BTreeSet<String>> = BTreeMap::new();
    for file in rust_files(&root().join("src")) {
        let module = module_of(&file);
        let Some(own) = layer(&module) else { continue }; // lib.rs, main.rs: the top
        let code = code_only(&std::fs::read_to_string(&file).unwrap());
        for used in imported_modules(&code) {
            let Some(theirs) = layer(&used) else { continue }; // the crate root's re-exports
            if used != module {
                edges.entry(module.clone()).or_default().insert(used.clone());
            }
            if theirs > own {
                wrong.push(format!("{} ({module}) uses crate::{used}, a layer above it", file.display()));
            }
        }
    }
    assert!(wrong.is_empty(), "imports back up:\n{}", wrong.join("\n"));
    // The core uses no shell; the shell (its links among it) uses the core.
    assert!(!edges.get("gateway::core").is_some_and(|e| e.contains("gateway::shell")));
    assert!(edges.get("gateway::shell").is_some_and(|e| e.contains("gateway::core")));
}

#[test]
fn functions_are_short_enough_to_read() {
    let mut long = Vec::new();
    let mut longest = (0, String::new());
    for file in rust_files(&root().join("src")) {
        let rel = file.strip_prefix(root()).unwrap().display().to_string();
        let limit = if rel.starts_with("src/gateway/core/") || rel.starts_with("src/cli/") {
            LONGEST_IN_CORE_AND_CLI
        } else {
            LONGEST
        };
        let code = code_only(&std::fs::read_to_string(&file).unwrap());
        for (name, line, len) in functions(&code) {
            if len > limit {
                long.push(format!("{rel}:{line} {name}: {len} lines (at most {limit})"));
            }
            if len > longest.0 {
                longest = (len, format!("{rel}:{line} {name}"));
            }
        }
    }
    assert!(long.is_empty(), "functions too long:\n{}", long.join("\n"));
    println!("longest function in src/: {} lines ({})", longest.0, longest.1);
}

/// The scanner itself: braces in strings, comments and characters are not the code's, and
/// lifetimes are not characters.
#[test]
fn the_function_scanner_counts_what_it_should() {
    let text = "fn a<'x>(s: &'x str) -> char {\n    let _ = \"}}\"; // }\n    '}'\n}\nfn b() {}\n";
    let found = functions(&code_only(text));
    assert_eq!(found, vec![("a".to_string(), 1, 4), ("b".to_string(), 5, 1)]);
    assert_eq!(imported_modules(&code_only("use crate::gateway::core::X; // crate::lab\n")), vec!["gateway::core"]);
}

#[test]
fn every_test_file_is_in_the_testing_page() {
    let page = std::fs::read_to_string(root().join("docs/testing.md")).unwrap();
    let mut missing = Vec::new();
    for dir in ["tests", "firmware-sim/tests", "protocol/tests"] {
        for entry in std::fs::read_dir(root().join(dir)).unwrap() {
            let p = entry.unwrap().path();
            if p.extension().is_some_and(|e| e == "rs") {
                let rel = format!("{dir}/{}", p.file_name().unwrap().to_string_lossy());
                if !page.contains(&format!("`{rel}`")) {
                    missing.push(rel);
                }
            }
        }
    }
    assert!(missing.is_empty(), "docs/testing.md does not list: {}", missing.join(", "));
}

#[test]
fn every_python_peer_sits_beside_its_test() {
    let mut wrong = Vec::new();
    for dir in ["tests", "firmware-sim/tests", "protocol/tests"] {
        for entry in std::fs::read_dir(root().join(dir)).unwrap() {
            let p = entry.unwrap().path();
            if p.extension().is_some_and(|e| e == "py") {
                wrong.push(format!("{} (peers go in {dir}/peers/)", p.display()));
            }
        }
        let peers = root().join(dir).join("peers");
        let Ok(entries) = std::fs::read_dir(&peers) else { continue };
        for entry in entries {
            let p = entry.unwrap().path();
            let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
            // `_name.py`: a module the peers share, not a peer.
            if p.extension().is_some_and(|e| e == "py") && !stem.starts_with('_') {
                let test = root().join(dir).join(format!("{stem}.rs"));
                if !test.exists() {
                    wrong.push(format!("{} has no test {}", p.display(), test.display()));
                }
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}
