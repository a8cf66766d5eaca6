//! The manual and the reference docs hold together: the README is a manual
//! of at most 300 lines with the two commands, nothing in the product speaks
//! of how its development was organised, every repository path a doc or a
//! `--help` text names exists, and `schemas/README.md` indexes every schema.

use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Text files under `dir` (recursively) with one of `exts`.
fn files(dir: &Path, exts: &[&str]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let Ok(rd) = std::fs::read_dir(dir) else {
        return out;
    };
    let mut entries: Vec<PathBuf> = rd.map(|e| e.unwrap().path()).collect();
    entries.sort();
    for p in entries {
        let name = p.file_name().unwrap().to_string_lossy().to_string();
        if name == "node_modules" || name == "target" || name.starts_with('.') {
            continue;
        }
        if p.is_dir() {
            out.extend(files(&p, exts));
        } else if p.extension().is_some_and(|e| exts.iter().any(|x| e == *x)) {
            out.push(p);
        }
    }
    out
}

fn rel(p: &Path) -> String {
    p.strip_prefix(root()).unwrap_or(p).display().to_string()
}

const README_COMMANDS: [&str; 2] = [
    "bash .ci/setup-debian && cargo run --release -- demo",
    "bash .ci/setup-debian test && cargo test --locked",
];

#[test]
fn readme_is_a_manual_of_at_most_300_lines_with_the_two_commands() {
    let text = std::fs::read_to_string(root().join("README.md")).unwrap();
    let lines = text.lines().count();
    assert!(lines <= 300, "README.md has {lines} lines (at most 300)");
    for c in README_COMMANDS {
        assert!(text.contains(c), "README.md lacks the command `{c}`");
    }
    // CI runs the second command.
    let ci = std::fs::read_to_string(root().join(".ci/run")).unwrap();
    assert!(
        ci.contains(README_COMMANDS[1]),
        ".ci/run does not run the README's test command"
    );
}

/// Words of the development process: a numbered step or ticket. Matches
/// `<word> <number>` for the two words, case-insensitively.
fn process_words(line: &str) -> Option<String> {
    let lower = line.to_ascii_lowercase();
    for word in ["stop ", "issue "] {
        let mut from = 0;
        while let Some(i) = lower[from..].find(word) {
            let at = from + i;
            let after = &lower[at + word.len()..];
            let starts_word = at == 0
                || !(lower.as_bytes()[at - 1].is_ascii_alphanumeric()
                    || lower.as_bytes()[at - 1] == b'-');
            if starts_word && after.starts_with(|c: char| c.is_ascii_digit()) {
                let end = (at + word.len() + 8).min(line.len());
                return Some(line.get(at..end).unwrap_or(line).to_string());
            }
            from = at + word.len();
        }
    }
    None
}

#[test]
fn the_process_word_check_sees_numbered_steps_and_tickets() {
    // Built at run time so that this file passes its own check.
    let (step, ticket) = ("Stop", "issue");
    assert!(process_words(&format!("as measured at {step} 41, the fit")).is_some());
    assert!(process_words(&format!("({ticket} 13 item 4)")).is_some());
    assert!(process_words(&format!("a non-{} 3 s run", step.to_lowercase())).is_none());
    assert!(process_words("stop the watch").is_none());
    assert!(process_words(&format!("t{ticket} 3")).is_none());
}

#[test]
fn no_words_of_the_development_process_in_the_product() {
    let r = root();
    let mut hits = Vec::new();
    let mut all = vec![r.join("README.md")];
    for dir in ["docs", "src", "tests", "examples", "schemas", "pipelines"] {
        all.extend(files(
            &r.join(dir),
            &["md", "rs", "toml", "json", "grid", "py", "sh", "txt"],
        ));
    }
    for f in all {
        let Ok(text) = std::fs::read_to_string(&f) else {
            continue;
        };
        for (n, line) in text.lines().enumerate() {
            if let Some(w) = process_words(line) {
                hits.push(format!("{}:{}: {w}", rel(&f), n + 1));
            }
        }
    }
    assert!(
        hits.is_empty(),
        "development-process words:\n{}",
        hits.join("\n")
    );
}

/// Repository paths (`docs/...`, `schemas/...`, `examples/...`,
/// `pipelines/...`, `src/...`, `tests/...`) named in `text`.
fn repo_paths(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for prefix in [
        "docs/",
        "schemas/",
        "examples/",
        "pipelines/",
        "src/",
        "tests/",
    ] {
        let mut from = 0;
        while let Some(i) = text[from..].find(prefix) {
            let at = from + i;
            from = at + prefix.len();
            let before = text[..at].chars().next_back();
            if before.is_some_and(|c| {
                c.is_ascii_alphanumeric() || c == '/' || c == '_' || c == '-' || c == '.'
            }) {
                continue;
            }
            let tail: String = text[at..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || matches!(c, '/' | '.' | '_' | '-'))
                .collect();
            let tail = tail.trim_end_matches(['.', '/']).to_string();
            // Only file names with an extension: a folder or a glob is prose.
            let last = tail.rsplit('/').next().unwrap_or("");
            if last.contains('.') && !tail.contains('*') && !tail.contains("..") {
                out.push(tail);
            }
        }
    }
    out
}

#[test]
fn every_repository_path_the_docs_and_help_texts_name_exists() {
    let r = root();
    let mut sources = vec![r.join("README.md")];
    sources.extend(files(&r.join("src"), &["rs"]));
    sources.extend(files(&r.join("docs"), &["md"]));
    sources.extend(files(&r.join("schemas"), &["md"]));
    let mut missing = Vec::new();
    for f in sources {
        let text = std::fs::read_to_string(&f).unwrap();
        for p in repo_paths(&text) {
            if !r.join(&p).exists() {
                missing.push(format!("{} names {p}", rel(&f)));
            }
        }
    }
    missing.sort();
    missing.dedup();
    assert!(
        missing.is_empty(),
        "named but missing:\n{}",
        missing.join("\n")
    );
}

#[test]
fn schemas_readme_indexes_every_schema() {
    let dir = root().join("schemas");
    let index = std::fs::read_to_string(dir.join("README.md")).unwrap();
    let mut unlisted = Vec::new();
    for f in files(&dir, &["md", "json"]) {
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        if name != "README.md" && !index.contains(&name) {
            unlisted.push(name);
        }
    }
    assert!(
        unlisted.is_empty(),
        "schemas/README.md does not index: {unlisted:?}"
    );
}

/// Relative Markdown links (`[text](path)`, `path#anchor`) in `text`.
fn md_links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(i) = text[from..].find("](") {
        let at = from + i + 2;
        from = at;
        let Some(end) = text[at..].find(')') else {
            break;
        };
        let target = text[at..at + end].trim();
        let target = target.split('#').next().unwrap_or("");
        if target.is_empty()
            || target.contains("://")
            || target.starts_with("mailto:")
            || target.contains(' ')
        {
            continue;
        }
        out.push(target.to_string());
    }
    out
}

#[test]
fn every_relative_markdown_link_resolves() {
    let r = root();
    let mut docs = vec![r.join("README.md")];
    for dir in ["docs", "schemas", "examples", "pipelines", "benches"] {
        docs.extend(files(&r.join(dir), &["md"]));
    }
    let mut broken = Vec::new();
    for f in docs {
        let text = std::fs::read_to_string(&f).unwrap();
        for link in md_links(&text) {
            if !f.parent().unwrap().join(&link).exists() {
                broken.push(format!("{} -> {link}", rel(&f)));
            }
        }
    }
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}
