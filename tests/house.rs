//! The shape of the code, held by a test: modules import only the layers below them (so
//! there is no import back up), no two files of any crate import each other round a circle,
//! functions stay short enough to read, every
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

/// The longest function anywhere in any crate (`src/`, `firmware-sim/`, `protocol/`), and
/// in the core and the CLI, lines.
const LONGEST: usize = 80;
const LONGEST_IN_CORE_AND_CLI: usize = 60;
/// The longest source file in any crate, lines (its unit tests, in a file of their own,
/// count apart).
const LONGEST_FILE: usize = 800;

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
    let files = ["src", "firmware-sim/src", "protocol/src"].iter().flat_map(|c| rust_files(&root().join(c)));
    for file in files {
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
    println!("longest function in any crate: {} lines ({})", longest.0, longest.1);
}

#[test]
fn source_files_are_short_enough_to_read() {
    let mut long = Vec::new();
    let files = ["src", "firmware-sim/src", "protocol/src"].iter().flat_map(|c| rust_files(&root().join(c)));
    for file in files {
        let lines = std::fs::read_to_string(&file).unwrap().lines().count();
        if lines > LONGEST_FILE {
            long.push(format!(
                "{}: {lines} lines (at most {LONGEST_FILE})",
                file.strip_prefix(root()).unwrap().display()
            ));
        }
    }
    assert!(long.is_empty(), "files too long:\n{}", long.join("\n"));
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

/// The file of module `path` (its segments below the crate's `src/`), if there is one.
fn module_file(src: &Path, path: &[String]) -> Option<PathBuf> {
    if path.is_empty() {
        return Some(src.join("lib.rs"));
    }
    let joined: PathBuf = path.iter().collect();
    [src.join(&joined).with_extension("rs"), src.join(&joined).join("mod.rs")].into_iter().find(|f| f.exists())
}

/// The module path of a file of a crate's `src/` (`planner/room.rs`: `["planner", "room"]`).
fn module_path(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap().with_extension("");
    let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
    if parts.last().is_some_and(|p| p == "mod" || p == "lib" || p == "main") {
        parts.pop();
    }
    parts
}

/// The paths a file names through `crate::`, `super::` and `self::`, as module paths from
/// the crate's root; a group (`super::{a::X, b}`) gives one path for each of its items.
fn named_paths(code: &str, own: &[String]) -> Vec<Vec<String>> {
    let word = |s: &str| s.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect::<String>();
    let mut out = Vec::new();
    for (at, _) in code.match_indices("::") {
        // Only the start of a path: the word before `::` not itself after another `::`.
        let before = &code[..at];
        let head: String = before.chars().rev().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        let head: String = head.chars().rev().collect();
        if before[..before.len() - head.len()].ends_with("::") {
            continue;
        }
        // From the file's own module: `self` is it, `super` its parent.
        let mut base: Vec<String> = match head.as_str() {
            "crate" => Vec::new(),
            "self" => own.to_vec(),
            "super" => {
                let mut b = own.to_vec();
                b.pop();
                b
            }
            _ => continue,
        };
        if head == "super" && own.is_empty() {
            continue;
        }
        let mut rest = &code[at + 2..];
        // More `super::`s.
        while let Some(r) = rest.strip_prefix("super::") {
            base.pop();
            rest = r;
        }
        let mut path = base;
        loop {
            let w = word(rest);
            if w.is_empty() {
                break;
            }
            path.push(w.clone());
            rest = &rest[w.len()..];
            match rest.strip_prefix("::") {
                Some(r) => rest = r,
                None => break,
            }
        }
        if let Some(group) = rest.strip_prefix('{') {
            // The group's items at its first level, each by its first segment.
            let (mut depth, mut items, mut item) = (0, Vec::new(), String::new());
            for ch in group.chars() {
                match ch {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        items.push(std::mem::take(&mut item));
                        continue;
                    }
                    _ => {}
                }
                item.push(ch);
            }
            items.push(item);
            for first in items.iter().map(|i| word(i.trim())).filter(|w| !w.is_empty() && w != "self") {
                let mut p = path.clone();
                p.push(first);
                out.push(p);
            }
        }
        out.push(path);
    }
    // `use child::X;`: a path from the file's own module (2018 paths), which resolves to
    // a file only when `child` is a module below it.
    for (at, _) in code.match_indices("use ") {
        let starts_word = at == 0 || !code[..at].ends_with(|c: char| c.is_alphanumeric() || c == '_');
        let first = word(&code[at + 4..]);
        if starts_word && !first.is_empty() && !["crate", "self", "super"].contains(&first.as_str()) {
            let mut p = own.to_vec();
            p.push(first);
            out.push(p);
        }
    }
    out
}

/// Import circles among a crate's files: `a.rs` naming something of `b.rs` and `b.rs`
/// naming something of `a.rs`, directly or round a longer loop. A module naming its own
/// parent's items (`super::X` in a child) is not counted: a parent holds what its children
/// share.
fn import_circles(src: &Path) -> Vec<String> {
    let files = rust_files(src);
    let mut edges: BTreeMap<PathBuf, std::collections::BTreeSet<PathBuf>> = BTreeMap::new();
    for file in &files {
        let own = module_path(src, file);
        let code = code_only(&std::fs::read_to_string(file).unwrap());
        let targets = edges.entry(file.clone()).or_default();
        for path in named_paths(&code, &own) {
            let target = (0..=path.len()).rev().find_map(|n| module_file(src, &path[..n]));
            let Some(target) = target.filter(|t| t != file) else { continue };
            let target_module = module_path(src, &target);
            // An ancestor of this file's module (its parent, the crate root): not an edge.
            if own.starts_with(&target_module) {
                continue;
            }
            targets.insert(target);
        }
    }
    // Each strongly connected set of more than one file is a circle.
    let mut circles = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    let reach = |from: &PathBuf| {
        let mut stack = vec![from.clone()];
        let mut reached = std::collections::BTreeSet::new();
        while let Some(f) = stack.pop() {
            for next in edges.get(&f).into_iter().flatten() {
                if reached.insert(next.clone()) {
                    stack.push(next.clone());
                }
            }
        }
        reached
    };
    for file in &files {
        if seen.contains(file) {
            continue;
        }
        let ahead = reach(file);
        let circle: Vec<&PathBuf> = ahead.iter().filter(|f| *f == file || reach(f).contains(file)).collect();
        if circle.len() > 1 || (circle.len() == 1 && circle[0] != file) {
            let mut names: Vec<String> =
                circle.iter().map(|f| f.strip_prefix(root()).unwrap_or(f).display().to_string()).collect();
            names.sort();
            names.dedup();
            seen.extend(circle.into_iter().cloned());
            circles.push(names.join(" <-> "));
        }
    }
    circles
}

#[test]
fn no_import_circles_in_any_crate() {
    let mut all = Vec::new();
    for krate in ["src", "firmware-sim/src", "protocol/src"] {
        all.extend(import_circles(&root().join(krate)));
    }
    assert!(all.is_empty(), "import circles:\n{}", all.join("\n"));
}

#[test]
fn the_circle_finder_finds_a_circle() {
    let dir = std::env::temp_dir().join(format!("flowgate-house-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("planner")).unwrap();
    std::fs::write(dir.join("lib.rs"), "pub mod planner;\n").unwrap();
    std::fs::write(dir.join("planner/mod.rs"), "pub mod a;\npub mod b;\npub use a::A;\n").unwrap();
    std::fs::write(dir.join("planner/a.rs"), "use super::{b::B, A2};\npub struct A;\n").unwrap();
    std::fs::write(dir.join("planner/b.rs"), "use crate::planner::a::A;\nuse super::Shared;\npub struct B;\n").unwrap();
    let circles = import_circles(&dir);
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(circles.len(), 1, "{circles:?}");
    assert!(circles[0].ends_with("planner/a.rs <-> ") || circles[0].ends_with("planner/b.rs"), "{circles:?}");
}

/// The core asks the same of either motor backend: `MotorMaster`'s variants are named
/// only inside `src/gateway/core/motors/`.
#[test]
fn no_branch_on_the_motor_backend_outside_motors() {
    let mut found = Vec::new();
    for file in rust_files(&root().join("src")) {
        if file.starts_with(root().join("src/gateway/core/motors")) {
            continue;
        }
        let code = code_only(&std::fs::read_to_string(&file).unwrap());
        for name in ["MotorMaster::Board", "MotorMaster::Cia402", "motors::MotorMaster::"] {
            if code.contains(name) {
                found.push(format!("{} names {name}", file.strip_prefix(root()).unwrap().display()));
            }
        }
    }
    assert!(found.is_empty(), "{}", found.join("\n"));
}

/// The core's counts have owners: each of `Counters`' fields is written in one module of
/// the core (a file, or `motors/`), through `counters.FIELD` or its short `c.FIELD` (the
/// core's convention); the motors count in a `MotorCounters` of their own.
#[test]
fn every_counter_is_written_in_one_module() {
    let core = root().join("src/gateway/core");
    let fields = std::fs::read_to_string(core.join("counters.rs")).unwrap();
    let fields: Vec<&str> =
        fields.lines().filter_map(|l| l.trim().strip_prefix("pub ")?.strip_suffix(": u64,")).collect();
    assert!(fields.len() > 40, "{fields:?}");
    let mut writers: BTreeMap<String, std::collections::BTreeSet<String>> = BTreeMap::new();
    for file in rust_files(&core) {
        let rel = file.strip_prefix(&core).unwrap().display().to_string();
        if rel.ends_with("tests.rs") {
            continue;
        }
        let module = rel.split('/').next().unwrap().to_string();
        let code = code_only(&std::fs::read_to_string(&file).unwrap());
        for field in &fields {
            for receiver in ["counters.", "c."] {
                let written = code.match_indices(&format!("{receiver}{field}")).any(|(at, m)| {
                    let before = code[..at].chars().next_back().is_none_or(|c| !c.is_alphanumeric() && c != '_');
                    let after = code[at + m.len()..].trim_start();
                    let assigns = ["+=", "-=", "|="].iter().any(|op| after.starts_with(op))
                        || (after.starts_with('=') && !after.starts_with("=="));
                    before && assigns
                });
                if written {
                    writers.entry(field.to_string()).or_default().insert(module.clone());
                }
            }
        }
    }
    let shared: Vec<String> =
        writers.iter().filter(|(_, m)| m.len() > 1).map(|(f, m)| format!("{f}: written in {m:?}")).collect();
    assert!(shared.is_empty(), "counters written from more than one module:\n{}", shared.join("\n"));
    assert!(writers.len() > 40, "the scan finds the writes: {writers:?}");
}

/// docs/architecture.md names only what exists: every path it quotes, from the repository's
/// root or as the end of a path in it (`motors/board.rs`, `cycle.rs`).
#[test]
fn the_architecture_page_names_only_paths_that_exist() {
    let page = std::fs::read_to_string(root().join("docs/architecture.md")).unwrap();
    let mut paths: Vec<String> = Vec::new();
    let mut stack = vec![root()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            if p.is_dir() && (name == "target" || name == "corpus" || name.starts_with('.')) {
                continue;
            }
            let rel = p.strip_prefix(root()).unwrap().display().to_string();
            if p.is_dir() {
                paths.push(format!("{rel}/"));
                stack.push(p);
            } else {
                paths.push(rel);
            }
        }
    }
    // The operator's own config, named as the docs name it.
    const THE_USERS: &[&str] = &["rig.toml"];
    let mut missing = Vec::new();
    let mut quoted = 0;
    for token in page.split('`').skip(1).step_by(2) {
        let looks_like_path = !token.contains(' ')
            && (token.contains('/') || [".rs", ".md", ".py", ".toml", ".dbc"].iter().any(|e| token.ends_with(e)));
        let not_a_path = token.contains("::") || token.contains('<') || token.starts_with('/') || token.contains('*');
        if !looks_like_path || not_a_path || THE_USERS.contains(&token) {
            continue;
        }
        quoted += 1;
        let token = token.trim_start_matches("../");
        let exists = paths.iter().any(|p| p == token || p.ends_with(&format!("/{token}")));
        if !exists {
            missing.push(token.to_string());
        }
    }
    assert!(quoted > 30, "only {quoted} paths found: the scan is broken");
    assert!(missing.is_empty(), "docs/architecture.md names what does not exist: {missing:?}");
}
