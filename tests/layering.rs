//! The import graph of `src/`, read from the source text: math modules
//! (`geom`, `linalg`, `embed`, `sim`, `fit`, `yarn`, `anim`) never import the
//! file, process or orchestration layers (`io`, `pipeline`, `daemon`, `cli`),
//! and no two files import each other, directly or through others
//! (docs/design.md, "Layering").
//!
//! An edge A -> B means file A names an item that is defined in file B:
//! through a `use` (followed through `pub use` re-exports to the file that
//! defines the item) or a path such as `crate::sim::pd::step`. A re-export
//! itself is not an edge, and neither is code under `#[cfg(test)]`: a test
//! may build its fixtures from any layer.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

const MATH: &[&str] = &["geom", "linalg", "embed", "sim", "fit", "yarn", "anim"];
const OUTER: &[&str] = &["io", "pipeline", "daemon", "cli"];

#[derive(Debug, Clone, PartialEq)]
enum Tok {
    Ident(String),
    Punct(&'static str),
    Other,
}

/// Tokens of Rust source without comments, strings, chars and lifetimes.
fn tokenize(src: &str) -> Vec<Tok> {
    let b = src.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if c.is_ascii_whitespace() {
            i += 1;
        } else if c == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if c == b'/' && b.get(i + 1) == Some(&b'*') {
            let mut depth = 1;
            i += 2;
            while i < b.len() && depth > 0 {
                if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
                    depth += 1;
                    i += 2;
                } else if b[i] == b'*' && b.get(i + 1) == Some(&b'/') {
                    depth -= 1;
                    i += 2;
                } else {
                    i += 1;
                }
            }
        } else if c == b'r' && (b.get(i + 1) == Some(&b'#') || b.get(i + 1) == Some(&b'"')) {
            // Raw string r"..." or r#"..."#.
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&b'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&b'"') {
                out.push(Tok::Ident("r".into()));
                i += 1;
                continue;
            }
            j += 1;
            loop {
                if j >= b.len() {
                    break;
                }
                if b[j] == b'"' && (0..hashes).all(|k| b.get(j + 1 + k) == Some(&b'#')) {
                    j += 1 + hashes;
                    break;
                }
                j += 1;
            }
            out.push(Tok::Other);
            i = j;
        } else if c == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                if b[i] == b'\\' {
                    i += 1;
                }
                i += 1;
            }
            i += 1;
            out.push(Tok::Other);
        } else if c == b'\'' {
            // A char literal ('a', '\n', '\u{..}') or a lifetime ('a).
            if b.get(i + 1) == Some(&b'\\') {
                i += 2;
                while i < b.len() && b[i] != b'\'' {
                    i += 1;
                }
                i += 1;
            } else if b.get(i + 2) == Some(&b'\'') {
                i += 3;
            } else {
                i += 1;
                while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                    i += 1;
                }
            }
            out.push(Tok::Other);
        } else if c.is_ascii_alphabetic() || c == b'_' {
            let s = i;
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                i += 1;
            }
            out.push(Tok::Ident(src[s..i].to_string()));
        } else if c.is_ascii_digit() {
            while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_' || b[i] == b'.') {
                if b[i] == b'.' && !b.get(i + 1).is_some_and(|d| d.is_ascii_digit()) {
                    break;
                }
                i += 1;
            }
            out.push(Tok::Other);
        } else if c == b':' && b.get(i + 1) == Some(&b':') {
            out.push(Tok::Punct("::"));
            i += 2;
        } else {
            let p = match c {
                b'{' => "{",
                b'}' => "}",
                b'(' => "(",
                b')' => ")",
                b'[' => "[",
                b']' => "]",
                b';' => ";",
                b',' => ",",
                b'#' => "#",
                b'*' => "*",
                b'!' => "!",
                _ => "",
            };
            out.push(if p.is_empty() {
                Tok::Other
            } else {
                Tok::Punct(p)
            });
            i += 1;
        }
    }
    out
}

fn ident(t: &Tok) -> Option<&str> {
    match t {
        Tok::Ident(s) => Some(s),
        _ => None,
    }
}

/// One `use` leaf: the local name it binds (`None` for a glob) and its path.
#[derive(Debug, Clone)]
struct UseLeaf {
    name: Option<String>,
    path: Vec<String>,
}

/// Parses a use tree starting at `toks[i]` (after `use`), up to its `;`.
fn parse_use_tree(toks: &[Tok], i: &mut usize, prefix: &[String], out: &mut Vec<UseLeaf>) {
    let mut path: Vec<String> = prefix.to_vec();
    loop {
        match toks.get(*i) {
            Some(Tok::Punct("::")) => *i += 1,
            Some(Tok::Punct("{")) => {
                *i += 1;
                loop {
                    match toks.get(*i) {
                        Some(Tok::Punct("}")) => {
                            *i += 1;
                            return;
                        }
                        Some(Tok::Punct(",")) => *i += 1,
                        None => return,
                        _ => parse_use_tree(toks, i, &path, out),
                    }
                }
            }
            Some(Tok::Punct("*")) => {
                *i += 1;
                out.push(UseLeaf { name: None, path });
                return;
            }
            Some(Tok::Ident(s)) if s == "as" => {
                *i += 1;
                let alias = toks.get(*i).and_then(ident).unwrap_or("_").to_string();
                *i += 1;
                out.push(UseLeaf {
                    name: Some(alias),
                    path,
                });
                return;
            }
            Some(Tok::Ident(s)) => {
                path.push(s.clone());
                *i += 1;
            }
            _ => {
                // `,`, `}` or `;`: the leaf ends here.
                let name = path.last().cloned();
                if path.last().map(String::as_str) == Some("self") {
                    path.pop();
                    let name = path.last().cloned();
                    out.push(UseLeaf { name, path });
                } else if path.len() > prefix.len() {
                    out.push(UseLeaf { name, path });
                }
                return;
            }
        }
    }
}

/// What one module (a file or an inline `mod`) declares and names.
#[derive(Debug, Default, Clone)]
struct Module {
    file: String,
    /// Items defined here (fn, struct, enum, trait, type, const, static, macro, mod).
    defs: BTreeSet<String>,
    /// Re-exports: local name -> path (relative to this module, unresolved).
    reexports: BTreeMap<String, Vec<String>>,
    glob_reexports: Vec<Vec<String>>,
    /// Names bound by private `use`s (for the first segment of paths).
    aliases: BTreeMap<String, Vec<String>>,
    /// Paths this module's non-test code names, unresolved.
    refs: Vec<Vec<String>>,
    /// Declared as `#[cfg(test)] mod x;`: test code, not part of the graph.
    test_only: bool,
}

type ModPath = Vec<String>;

/// Reads one file into its modules (the file's own and inline ones).
fn scan_file(file: &str, base: &ModPath, src: &str, mods: &mut BTreeMap<ModPath, Module>) {
    let toks = tokenize(src);
    // Stack of (module path, brace depth at which it opened); the file's module is depth 0.
    let mut stack: Vec<(ModPath, usize)> = vec![(base.clone(), 0)];
    mods.entry(base.clone()).or_default().file = file.to_string();
    let mut depth = 0usize;
    // Depth at which a `#[cfg(test)]` item's braces opened: skip its contents.
    let mut test_until: Option<usize> = None;
    let mut cfg_test_pending = false;
    let mut i = 0;
    while i < toks.len() {
        let t = &toks[i];
        // `#[cfg(test)]` (also `#[cfg(all(test, ..))]`): the next item is test-only.
        if *t == Tok::Punct("#") && toks.get(i + 1) == Some(&Tok::Punct("[")) {
            let mut j = i + 2;
            let mut d = 1;
            let mut is_cfg_test = false;
            if toks.get(j).and_then(ident) == Some("cfg") {
                let mut k = j;
                while k < toks.len() && d > 0 {
                    match &toks[k] {
                        Tok::Punct("[") => d += 1,
                        Tok::Punct("]") => d -= 1,
                        Tok::Ident(s) if s == "test" => is_cfg_test = true,
                        Tok::Ident(s) if s == "not" => break,
                        _ => {}
                    }
                    k += 1;
                }
            }
            d = 1;
            while j < toks.len() && d > 0 {
                match toks[j] {
                    Tok::Punct("[") => d += 1,
                    Tok::Punct("]") => d -= 1,
                    _ => {}
                }
                j += 1;
            }
            if is_cfg_test && test_until.is_none() {
                cfg_test_pending = true;
            }
            i = j;
            continue;
        }
        match t {
            Tok::Punct("{") => {
                depth += 1;
                if cfg_test_pending && test_until.is_none() {
                    test_until = Some(depth);
                    cfg_test_pending = false;
                }
                i += 1;
                continue;
            }
            Tok::Punct("}") => {
                if test_until == Some(depth) {
                    test_until = None;
                }
                if stack.len() > 1 && stack.last().unwrap().1 == depth {
                    stack.pop();
                }
                depth = depth.saturating_sub(1);
                i += 1;
                continue;
            }
            Tok::Punct(";") => {
                // A `#[cfg(test)] mod x;` or `use` ends here.
                cfg_test_pending = false;
                i += 1;
                continue;
            }
            _ => {}
        }
        let in_test = test_until.is_some() || cfg_test_pending;
        let cur = stack.last().unwrap().0.clone();
        let Some(word) = ident(t) else {
            i += 1;
            continue;
        };
        // Visibility before `use`/`mod`/items.
        let is_pub = word == "pub";
        let mut j = i;
        if is_pub {
            j += 1;
            if toks.get(j) == Some(&Tok::Punct("(")) {
                while j < toks.len() && toks[j] != Tok::Punct(")") {
                    j += 1;
                }
                j += 1;
            }
        }
        let kw = toks.get(j).and_then(ident).unwrap_or("");
        if kw == "use" {
            let mut k = j + 1;
            let mut leaves = Vec::new();
            parse_use_tree(&toks, &mut k, &[], &mut leaves);
            while k < toks.len() && toks[k] != Tok::Punct(";") {
                k += 1;
            }
            if !in_test {
                let m = mods.entry(cur.clone()).or_default();
                for leaf in leaves {
                    if is_pub {
                        match leaf.name {
                            Some(n) => {
                                m.reexports.insert(n, leaf.path);
                            }
                            None => m.glob_reexports.push(leaf.path),
                        }
                    } else {
                        if let Some(n) = &leaf.name {
                            m.aliases.insert(n.clone(), leaf.path.clone());
                        }
                        m.refs.push(leaf.path);
                    }
                }
            }
            cfg_test_pending = false;
            i = k + 1;
            continue;
        }
        if kw == "mod" {
            if let Some(name) = toks.get(j + 1).and_then(ident) {
                let mut child = cur.clone();
                child.push(name.to_string());
                if !in_test {
                    mods.entry(cur.clone())
                        .or_default()
                        .defs
                        .insert(name.to_string());
                } else if toks.get(j + 2) == Some(&Tok::Punct(";")) {
                    mods.entry(child.clone()).or_default().test_only = true;
                }
                if toks.get(j + 2) == Some(&Tok::Punct("{")) {
                    if test_until.is_none() && cfg_test_pending {
                        // Inline test module: skipped wholesale below.
                    } else {
                        mods.entry(child.clone()).or_default().file = file.to_string();
                        stack.push((child, depth + 1));
                    }
                }
                i = j + 2;
                continue;
            }
        }
        if matches!(
            kw,
            "fn" | "struct" | "enum" | "trait" | "type" | "const" | "static" | "union"
        ) || (kw == "macro_rules" && toks.get(j + 1) == Some(&Tok::Punct("!")))
        {
            let off = if kw == "macro_rules" { 2 } else { 1 };
            if let Some(name) = toks.get(j + off).and_then(ident) {
                if !in_test {
                    mods.entry(cur.clone())
                        .or_default()
                        .defs
                        .insert(name.to_string());
                }
            }
            i = j + off + 1;
            continue;
        }
        // A path `a::b::c` in code.
        if toks.get(i + 1) == Some(&Tok::Punct("::")) && (i == 0 || toks[i - 1] != Tok::Punct("::"))
        {
            let mut path = vec![word.to_string()];
            let mut k = i + 1;
            while toks.get(k) == Some(&Tok::Punct("::")) {
                match toks.get(k + 1).and_then(ident) {
                    Some(s) => path.push(s.to_string()),
                    None => break,
                }
                k += 2;
            }
            if !in_test {
                mods.entry(cur.clone()).or_default().refs.push(path);
            }
            i = k;
            continue;
        }
        i += 1;
    }
}

struct Graph {
    mods: BTreeMap<ModPath, Module>,
}

impl Graph {
    fn from_sources(files: &BTreeMap<String, String>) -> Graph {
        let mut mods = BTreeMap::new();
        for (file, src) in files {
            if let Some(base) = module_path_of(file) {
                scan_file(file, &base, src, &mut mods);
            }
        }
        Graph { mods }
    }

    /// Turns a path named in module `at` into an absolute one, or None when it
    /// leaves the crate (std, a dependency, a local type's associated item).
    fn absolute(&self, at: &ModPath, path: &[String], depth: usize) -> Option<Vec<String>> {
        let first = path.first()?.as_str();
        let mut out: Vec<String>;
        let mut rest = &path[1..];
        match first {
            "crate" => out = vec![],
            "knitvox" => out = vec![],
            "self" => out = at.clone(),
            "super" => {
                out = at.clone();
                out.pop();
                while rest.first().map(String::as_str) == Some("super") {
                    out.pop();
                    rest = &rest[1..];
                }
            }
            name => {
                let m = self.mods.get(at)?;
                if let Some(target) = m.aliases.get(name) {
                    if depth > 8 {
                        return None;
                    }
                    let mut p = self.absolute(at, target, depth + 1)?;
                    p.extend(rest.iter().cloned());
                    return Some(p);
                }
                let mut child = at.clone();
                child.push(name.to_string());
                if self.mods.contains_key(&child) {
                    out = child;
                } else if at.is_empty() && self.mods.contains_key(&vec![name.to_string()]) {
                    out = vec![name.to_string()];
                } else if let Some(target) = m.reexports.get(name) {
                    let mut p = self.absolute(at, target, depth + 1)?;
                    p.extend(rest.iter().cloned());
                    return Some(p);
                } else {
                    return None;
                }
            }
        }
        out.extend(rest.iter().cloned());
        Some(out)
    }

    /// The file that defines the item an absolute path names.
    fn defining_file(&self, path: &[String], depth: usize) -> Option<String> {
        if depth > 16 {
            return None;
        }
        // Longest prefix that is a module.
        let mut n = path.len();
        while n > 0 && !self.mods.contains_key(&path[..n].to_vec()) {
            n -= 1;
        }
        let module = path[..n].to_vec();
        let m = self.mods.get(&module)?;
        let Some(item) = path.get(n) else {
            return Some(m.file.clone());
        };
        if m.defs.contains(item) {
            return Some(m.file.clone());
        }
        if let Some(target) = m.reexports.get(item) {
            let mut p = self.absolute(&module, target, 0)?;
            p.extend(path[n + 1..].iter().cloned());
            return self.defining_file(&p, depth + 1);
        }
        for g in &m.glob_reexports {
            if let Some(gm) = self.absolute(&module, g, 0) {
                let mut p = gm.clone();
                p.extend(path[n..].iter().cloned());
                if let Some(f) = self.defining_file(&p, depth + 1) {
                    if f != self
                        .mods
                        .get(&gm)
                        .map(|m| m.file.clone())
                        .unwrap_or_default()
                        || self.mods.get(&gm).is_some_and(|m| m.defs.contains(item))
                    {
                        return Some(f);
                    }
                }
            }
        }
        Some(m.file.clone())
    }

    fn is_test_only(&self, at: &ModPath) -> bool {
        (1..=at.len()).any(|n| {
            self.mods
                .get(&at[..n].to_vec())
                .is_some_and(|m| m.test_only)
        })
    }

    /// File-level edges (importer -> defining file), self-edges removed.
    fn edges(&self) -> BTreeMap<String, BTreeSet<String>> {
        self.edges_with_reasons()
            .into_iter()
            .map(|(k, v)| (k, v.into_keys().collect()))
            .collect()
    }

    /// Edges with the paths that make each one.
    fn edges_with_reasons(&self) -> BTreeMap<String, BTreeMap<String, BTreeSet<String>>> {
        let mut e: BTreeMap<String, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
        for (at, m) in &self.mods {
            if self.is_test_only(at) || m.file.is_empty() {
                continue;
            }
            e.entry(m.file.clone()).or_default();
            for r in &m.refs {
                let Some(abs) = self.absolute(at, r, 0) else {
                    continue;
                };
                if abs.is_empty() {
                    continue;
                }
                if let Some(f) = self.defining_file(&abs, 0) {
                    if f != m.file {
                        e.entry(m.file.clone())
                            .or_default()
                            .entry(f)
                            .or_default()
                            .insert(r.join("::"));
                    }
                }
            }
        }
        e
    }
}

/// `src/a/b.rs` -> [a, b]; `src/a/mod.rs` -> [a]; `src/lib.rs` -> [].
fn module_path_of(file: &str) -> Option<ModPath> {
    let rel = file.strip_prefix("src/")?.strip_suffix(".rs")?;
    if rel == "main" {
        return None;
    }
    if rel == "lib" {
        return Some(vec![]);
    }
    let mut parts: Vec<String> = rel.split('/').map(str::to_string).collect();
    if parts.last().map(String::as_str) == Some("mod") {
        parts.pop();
    }
    Some(parts)
}

fn top_module(file: &str) -> &str {
    let rel = file.strip_prefix("src/").unwrap_or(file);
    let first = rel.split('/').next().unwrap_or("");
    first.strip_suffix(".rs").unwrap_or(first)
}

/// Imports of an outer layer by a math module, as "file -> file" lines.
fn layering_violations(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<String> {
    let mut v = Vec::new();
    for (from, tos) in edges {
        if !MATH.contains(&top_module(from)) {
            continue;
        }
        for to in tos {
            if OUTER.contains(&top_module(to)) {
                v.push(format!("{from} -> {to}"));
            }
        }
    }
    v
}

/// Strongly connected groups of more than one file (Tarjan).
fn cycles(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct T<'a> {
        e: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        on: BTreeSet<&'a str>,
        stack: Vec<&'a str>,
        next: usize,
        out: Vec<Vec<String>>,
    }
    fn visit<'a>(t: &mut T<'a>, v: &'a str) {
        t.index.insert(v, t.next);
        t.low.insert(v, t.next);
        t.next += 1;
        t.stack.push(v);
        t.on.insert(v);
        let succ: Vec<&'a str> =
            t.e.get(v)
                .map(|s| s.iter().map(String::as_str).collect())
                .unwrap_or_default();
        for w in succ {
            if !t.index.contains_key(w) {
                visit(t, w);
                let lw = t.low[w];
                let lv = t.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if t.on.contains(w) {
                let iw = t.index[w];
                let lv = t.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if t.low[v] == t.index[v] {
            let mut group = Vec::new();
            loop {
                let w = t.stack.pop().unwrap();
                t.on.remove(w);
                group.push(w.to_string());
                if w == v {
                    break;
                }
            }
            if group.len() > 1 {
                group.sort();
                t.out.push(group);
            }
        }
    }
    let mut t = T {
        e: edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        on: BTreeSet::new(),
        stack: vec![],
        next: 0,
        out: vec![],
    };
    let nodes: Vec<&str> = edges.keys().map(String::as_str).collect();
    for v in nodes {
        if !t.index.contains_key(v) {
            visit(&mut t, v);
        }
    }
    t.out.sort();
    t.out
}

fn read_src(root: &Path) -> BTreeMap<String, String> {
    fn walk(dir: &Path, root: &Path, out: &mut BTreeMap<String, String>) {
        let mut entries: Vec<_> = std::fs::read_dir(dir)
            .expect("read src")
            .map(|e| e.unwrap().path())
            .collect();
        entries.sort();
        for p in entries {
            if p.is_dir() {
                walk(&p, root, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let rel = p
                    .strip_prefix(root)
                    .unwrap()
                    .to_string_lossy()
                    .replace('\\', "/");
                out.insert(rel, std::fs::read_to_string(&p).expect("read source"));
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(&root.join("src"), root, &mut out);
    out
}

fn real_graph() -> Graph {
    Graph::from_sources(&read_src(Path::new(env!("CARGO_MANIFEST_DIR"))))
}

/// Each cycle's edges with the paths that make them.
fn report(
    groups: &[Vec<String>],
    reasons: &BTreeMap<String, BTreeMap<String, BTreeSet<String>>>,
) -> String {
    let mut s = String::new();
    for g in groups {
        s.push_str(&format!("cycle of {} files:\n", g.len()));
        for f in g {
            for (t, why) in &reasons[f] {
                if g.contains(t) {
                    let why: Vec<&str> = why.iter().map(String::as_str).collect();
                    s.push_str(&format!("  {f} -> {t}: {}\n", why.join(", ")));
                }
            }
        }
    }
    s
}

#[test]
fn math_modules_import_no_io_pipeline_daemon_or_cli() {
    let v = layering_violations(&real_graph().edges());
    assert!(
        v.is_empty(),
        "math modules import outer layers:\n{}",
        v.join("\n")
    );
}

#[test]
fn no_file_level_import_cycle_in_src() {
    let g = real_graph();
    let c = cycles(&g.edges());
    assert!(
        c.is_empty(),
        "file-level import cycles:\n{}",
        report(&c, &g.edges_with_reasons())
    );
}

fn synthetic(files: &[(&str, &str)]) -> BTreeMap<String, BTreeSet<String>> {
    let m: BTreeMap<String, String> = files
        .iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    Graph::from_sources(&m).edges()
}

/// The checker itself: a planted `use crate::io` in `sim`, a two-file loop,
/// a loop through a re-export and a path in code are all seen; test code and
/// re-exports alone are not edges.
#[test]
fn the_checker_sees_planted_violations_and_cycles() {
    let lib = "pub mod io; pub mod sim; pub mod geom;";
    let planted = synthetic(&[
        ("src/lib.rs", lib),
        ("src/io/mod.rs", "pub fn read() {}"),
        ("src/sim/mod.rs", "pub mod pd;\npub use pd::Step;"),
        (
            "src/sim/pd.rs",
            "use crate::io;\npub struct Step; fn f() { io::read(); }",
        ),
        ("src/geom/mod.rs", "pub struct V;"),
    ]);
    assert_eq!(
        layering_violations(&planted),
        vec!["src/sim/pd.rs -> src/io/mod.rs".to_string()]
    );
    assert!(cycles(&planted).is_empty(), "a re-export is not an edge");

    let looped = synthetic(&[
        ("src/lib.rs", lib),
        ("src/io/mod.rs", ""),
        ("src/geom/mod.rs", "pub mod a; pub mod b; pub use b::B;"),
        ("src/geom/a.rs", "use super::B; pub struct A;"),
        (
            "src/geom/b.rs",
            "pub struct B; fn f() -> crate::geom::a::A { todo!() }",
        ),
        (
            "src/sim/mod.rs",
            "#[cfg(test)]\nmod tests { use crate::io::x; }",
        ),
    ]);
    assert_eq!(
        cycles(&looped),
        vec![vec![
            "src/geom/a.rs".to_string(),
            "src/geom/b.rs".to_string()
        ]]
    );
    assert!(
        layering_violations(&looped).is_empty(),
        "test code may use any layer"
    );
}
