//! One file's tokens to what the import graph needs from it: every path that may name another file of the crate
//! (`use` trees, flattened, and paths written inline in code), the child modules it declares, and which of
//! them are test-only. Resolving a path to a file is the graph's job (it knows every file); this module only
//! reads one file, and never fails: tokens it does not understand are stepped over.

use super::lexer::Tok;

/// A path as written, with the inline modules (`mod name { ... }`) it sits in, relative to its file's module:
/// `super` inside `mod inner { }` is the file's own module, not its parent.
#[derive(Debug, Clone)]
pub(crate) struct RawPath {
    pub inline: Vec<String>,
    pub segs: Vec<String>,
    /// For a `use` leaf, the name it brings into scope (its last segment or its `as` name): when that is a
    /// module, later paths starting at the name go through it (`use crate::rig;` then `rig::sim_link::X`).
    pub alias: Option<String>,
    /// A leaf of a `pub use` (any visibility): the name is re-exported, so a path through this file to it is
    /// followed on to where it comes from (`crate::Rig` with `pub use rig::Rig;` in lib.rs names rig.rs).
    pub reexport: bool,
}

/// `mod name;` (or an inline `mod name { }` when test-only), in the inline modules it sits in.
#[derive(Debug, Clone)]
pub(crate) struct ChildDecl {
    pub inline: Vec<String>,
    pub name: String,
    pub test: bool,
}

#[derive(Debug, Default)]
pub(crate) struct FileScan {
    pub paths: Vec<RawPath>,
    pub children: Vec<ChildDecl>,
    /// The file opens with `#![cfg(test)]`: all of it is test code.
    pub test_only: bool,
}

/// Use-tree groups nested deeper than this are garbage, not Rust anyone writes; the cap keeps hostile input
/// from exhausting the stack.
const MAX_GROUP_DEPTH: usize = 32;

pub(crate) fn scan(t: &[Tok]) -> FileScan {
    let mut s = Scanner {
        t,
        i: 0,
        frames: Vec::new(),
        out: FileScan::default(),
        pending_pub: false,
        in_pub_use: false,
    };
    s.run();
    s.out
}

struct Scanner<'a> {
    t: &'a [Tok],
    i: usize,
    /// One entry per open `{`: the module's name when it opened an inline `mod name {`.
    frames: Vec<Option<String>>,
    out: FileScan,
    /// The last item keyword seen was a visibility (`pub`, `pub(crate)`, ...).
    pending_pub: bool,
    /// The `use` tree being read is a `pub use`.
    in_pub_use: bool,
}

impl Scanner<'_> {
    fn ident(&self, k: usize) -> Option<&str> {
        match self.t.get(k) {
            Some(Tok::Ident(w)) => Some(w),
            _ => None,
        }
    }

    fn is(&self, k: usize, tok: &Tok) -> bool {
        self.t.get(k) == Some(tok)
    }

    fn inline(&self) -> Vec<String> {
        self.frames.iter().flatten().cloned().collect()
    }

    fn run(&mut self) {
        while let Some(tok) = self.t.get(self.i) {
            match tok {
                Tok::Punct('#') => self.attribute(),
                Tok::Punct('{') => {
                    self.frames.push(None);
                    self.i += 1;
                }
                Tok::Punct('}') => {
                    self.frames.pop();
                    self.i += 1;
                }
                Tok::Ident(w) => match w.as_str() {
                    "use" => {
                        self.in_pub_use = std::mem::take(&mut self.pending_pub);
                        self.i += 1;
                        self.use_tree(Vec::new(), 0);
                        self.in_pub_use = false;
                    }
                    "mod" => {
                        self.pending_pub = false;
                        self.module();
                    }
                    // `pub(crate)`, `pub(in crate::a)`: a visibility bound names an ancestor, not an import.
                    "pub" if self.is(self.i + 1, &Tok::Punct('(')) => {
                        self.i += 1;
                        self.skip_balanced();
                        self.pending_pub = true;
                    }
                    "pub" => {
                        self.i += 1;
                        self.pending_pub = true;
                    }
                    _ if self.is(self.i + 1, &Tok::PathSep) && !self.continues_path() => {
                        self.pending_pub = false;
                        self.inline_path();
                    }
                    _ => {
                        self.pending_pub = false;
                        self.i += 1;
                    }
                },
                _ => {
                    self.pending_pub = false;
                    self.i += 1;
                }
            }
        }
    }

    /// The identifier at `i` is a later segment of a path or a field/method name, not a path's start.
    fn continues_path(&self) -> bool {
        self.i > 0 && matches!(self.t[self.i - 1], Tok::PathSep | Tok::Punct('.'))
    }

    /// At `#`: an attribute. `#[cfg(test)]` makes the item after it (after any further attributes) test code,
    /// left out of the graph; `#![cfg(test)]` at the top of the file makes the whole file test code.
    fn attribute(&mut self) {
        let inner = self.is(self.i + 1, &Tok::Punct('!'));
        let open = self.i + 1 + usize::from(inner);
        if !self.is(open, &Tok::Punct('[')) {
            self.i += 1;
            return;
        }
        self.i = open;
        let body_start = open + 1;
        self.skip_balanced();
        let body = &self.t[body_start.min(self.i)..self.i.saturating_sub(1).max(body_start)];
        if !is_cfg_test(body) {
            return;
        }
        if inner {
            if self.frames.is_empty() {
                self.out.test_only = true;
            }
            return;
        }
        while self.is(self.i, &Tok::Punct('#')) && self.is(self.i + 1, &Tok::Punct('[')) {
            self.i += 1;
            self.skip_balanced();
        }
        self.test_item();
    }

    /// At the start of a `#[cfg(test)]` item: skip it, noting a test module so its file (and an inline test
    /// module's own child files) stay out of the graph.
    fn test_item(&mut self) {
        if self.ident(self.i) == Some("pub") {
            self.i += 1;
            if self.is(self.i, &Tok::Punct('(')) {
                self.skip_balanced();
            }
        }
        if self.ident(self.i) == Some("mod")
            && let Some(name) = self.ident(self.i + 1)
        {
            let decl = ChildDecl {
                inline: self.inline(),
                name: name.to_string(),
                test: true,
            };
            self.out.children.push(decl);
        }
        let item = matches!(
            self.ident(self.i),
            Some(
                "fn" | "mod"
                    | "struct"
                    | "enum"
                    | "union"
                    | "impl"
                    | "trait"
                    | "use"
                    | "const"
                    | "static"
                    | "type"
                    | "extern"
                    | "unsafe"
                    | "async"
                    | "macro_rules"
                    | "let"
            )
        );
        // An item ends at its `;` or its body's `}`; anything else (a field, a match arm) also at a `,`, and
        // never past the closer of the block it sits in.
        let mut depth = 0usize;
        while let Some(tok) = self.t.get(self.i) {
            match tok {
                Tok::Punct('(' | '[' | '{') => depth += 1,
                Tok::Punct(c @ (')' | ']' | '}')) => {
                    if depth == 0 {
                        return;
                    }
                    depth -= 1;
                    if depth == 0 && *c == '}' {
                        self.i += 1;
                        return;
                    }
                }
                Tok::Punct(';') if depth == 0 => {
                    self.i += 1;
                    return;
                }
                Tok::Punct(',') if depth == 0 && !item => {
                    self.i += 1;
                    return;
                }
                _ => {}
            }
            self.i += 1;
        }
    }

    /// At an opening `(`, `[` or `{`: move past its matching closer (or to the end of a truncated file).
    fn skip_balanced(&mut self) {
        let mut depth = 0usize;
        while let Some(tok) = self.t.get(self.i) {
            self.i += 1;
            match tok {
                Tok::Punct('(' | '[' | '{') => depth += 1,
                Tok::Punct(')' | ']' | '}') => {
                    depth = depth.saturating_sub(1);
                    if depth == 0 {
                        return;
                    }
                }
                _ => {}
            }
        }
    }

    /// At `mod`: `mod name;` declares a child file (not itself an edge); `mod name {` opens an inline module
    /// whose contents count as this file's.
    fn module(&mut self) {
        self.i += 1;
        let Some(name) = self.ident(self.i).map(str::to_string) else {
            return;
        };
        if self.is(self.i + 1, &Tok::Punct(';')) {
            self.out.children.push(ChildDecl {
                inline: self.inline(),
                name,
                test: false,
            });
            self.i += 2;
        } else if self.is(self.i + 1, &Tok::Punct('{')) {
            self.frames.push(Some(name));
            self.i += 2;
        } else {
            self.i += 1;
        }
    }

    /// After `use` (or inside a group, with the group's prefix): one use tree, every leaf path recorded.
    fn use_tree(&mut self, mut segs: Vec<String>, depth: usize) {
        loop {
            match self.t.get(self.i) {
                Some(Tok::PathSep) => {
                    // A leading `::` names an external crate; the marker keeps it from resolving locally.
                    if segs.is_empty() {
                        segs.push("::".to_string());
                    }
                    self.i += 1;
                }
                Some(Tok::Ident(w)) if w != "as" => {
                    // `{self, X}` in a group is the group's prefix itself.
                    if w != "self" || segs.is_empty() {
                        segs.push(w.clone());
                    }
                    self.i += 1;
                    if !self.is(self.i, &Tok::PathSep) {
                        break;
                    }
                }
                Some(Tok::Punct('*')) => {
                    segs.push("*".to_string());
                    self.i += 1;
                    break;
                }
                Some(Tok::Punct('{')) => {
                    self.i += 1;
                    self.use_group(&segs, depth);
                    return;
                }
                _ => break,
            }
        }
        let mut alias = segs.last().filter(|l| *l != "*").cloned();
        if self.ident(self.i) == Some("as") {
            alias = self.ident(self.i + 1).filter(|a| *a != "_").map(str::to_string);
            self.i += 2;
        }
        if !segs.is_empty() {
            self.out.paths.push(RawPath {
                inline: self.inline(),
                segs,
                alias,
                reexport: self.in_pub_use,
            });
        }
    }

    /// Just inside a use group's `{`: each comma-separated tree under the prefix, up to the closing `}`.
    fn use_group(&mut self, prefix: &[String], depth: usize) {
        while let Some(tok) = self.t.get(self.i) {
            match tok {
                Tok::Punct('}') => {
                    self.i += 1;
                    return;
                }
                Tok::Punct(',') => self.i += 1,
                _ => {
                    let before = self.i;
                    if depth < MAX_GROUP_DEPTH {
                        self.use_tree(prefix.to_vec(), depth + 1);
                    }
                    if self.i == before {
                        self.i += 1;
                    }
                }
            }
        }
    }

    /// At the first identifier of a path written in code (`crate::engine::EngineError`, `super::Foo`,
    /// `supervise::Device`); turbofish and the like end it.
    fn inline_path(&mut self) {
        let mut segs = Vec::new();
        if let Some(w) = self.ident(self.i) {
            segs.push(w.to_string());
        }
        self.i += 1;
        while self.is(self.i, &Tok::PathSep)
            && let Some(w) = self.ident(self.i + 1)
        {
            segs.push(w.to_string());
            self.i += 2;
        }
        self.out.paths.push(RawPath {
            inline: self.inline(),
            segs,
            alias: None,
            reexport: false,
        });
    }
}

/// `cfg(test)` or `cfg(all(.., test, ..))`: code that exists only in the crate's own test build. `cfg(any(test,
/// ..))` and `cfg(not(test))` are compiled in normal builds too, so they stay in the graph.
fn is_cfg_test(body: &[Tok]) -> bool {
    let id = |k: usize| match body.get(k) {
        Some(Tok::Ident(w)) => Some(w.as_str()),
        _ => None,
    };
    let p = |k: usize, c: char| body.get(k) == Some(&Tok::Punct(c));
    if id(0) != Some("cfg") || !p(1, '(') {
        return false;
    }
    if id(2) == Some("test") && p(3, ')') && body.len() == 4 {
        return true;
    }
    if id(2) != Some("all") || !p(3, '(') {
        return false;
    }
    // Only a `test` directly inside `all(...)` counts: `all(not(test), ..)` is the opposite.
    let mut depth = 0usize;
    for tok in &body[4..] {
        match tok {
            Tok::Punct('(') => depth += 1,
            Tok::Punct(')') if depth == 0 => return false,
            Tok::Punct(')') => depth -= 1,
            Tok::Ident(w) if w == "test" && depth == 0 => return true,
            _ => {}
        }
    }
    false
}
