//! The file graph and its loops: each scanned path resolved to the file that defines what it names, then the
//! strongly connected components (Tarjan) with more than one file.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};

use super::report::{Loop, Tie};
use super::scan::{FileScan, RawPath};
use super::tree::Root;

/// A compilation root: the crate's index and which of its roots. Paths resolve only inside one: a `gonio_x::`
/// path cannot make a file loop, since Cargo forbids dependency cycles between crates.
pub(crate) type Unit = (usize, Root);

/// Re-exports followed from one path before giving up (a chain longer than this is not code anyone writes).
const MAX_REEXPORT_HOPS: usize = 16;

/// One scanned source file.
#[derive(Debug)]
pub(crate) struct Node {
    /// Relative to the workspace root, `/`-separated.
    pub rel: String,
    pub unit: Unit,
    pub module: Vec<String>,
    pub scan: FileScan,
}

pub(crate) fn loops<'a>(nodes: &'a [Node]) -> Vec<Loop> {
    let tests = test_modules(nodes);
    let is_test =
        |n: &Node| (0..=n.module.len()).any(|k| tests.contains(&(n.unit.clone(), n.module[..k].to_vec())));
    let live: Vec<bool> = nodes.iter().map(|n| !is_test(n)).collect();
    let mut files: HashMap<(&Unit, &[String]), usize> = HashMap::new();
    for (i, n) in nodes.iter().enumerate().filter(|(i, _)| live[*i]) {
        files.insert((&n.unit, &n.module[..]), i);
    }

    let scope_of = |n: &'a Node| Scope {
        module: &n.module,
        children: n
            .scan
            .children
            .iter()
            .map(|c| (&c.inline[..], c.name.as_str()))
            .collect(),
        aliases: HashMap::new(),
    };
    let mut scopes: Vec<Scope<'_>> = nodes.iter().map(scope_of).collect();
    for (i, n) in nodes.iter().enumerate().filter(|(i, _)| live[*i]) {
        // First the modules that `use` brings into scope by name, so that paths through them resolve below.
        for raw in &n.scan.paths {
            if let (Some(alias), Some(abs)) = (&raw.alias, scopes[i].absolute(raw))
                && files.contains_key(&(&n.unit, &abs[..]))
            {
                scopes[i].aliases.insert((&raw.inline[..], alias.as_str()), abs);
            }
        }
    }
    // What each file re-exports (`pub use`), by the path under which the name is seen from outside: a path
    // through the re-exporting file to that name is followed on to where the name comes from.
    let mut reexports: HashMap<(&Unit, Vec<String>), Vec<String>> = HashMap::new();
    for (i, n) in nodes.iter().enumerate().filter(|(i, _)| live[*i]) {
        for raw in n.scan.paths.iter().filter(|r| r.reexport) {
            if let (Some(alias), Some(abs)) = (&raw.alias, scopes[i].absolute(raw)) {
                let seen_as = n
                    .module
                    .iter()
                    .chain(&raw.inline)
                    .chain([alias])
                    .cloned()
                    .collect();
                reexports.insert((&n.unit, seen_as), abs);
            }
        }
    }

    let mut edges: BTreeMap<(usize, usize), BTreeSet<String>> = BTreeMap::new();
    for (i, n) in nodes.iter().enumerate().filter(|(i, _)| live[*i]) {
        let file_of = |abs: &[String]| files.get(&(&n.unit, abs)).copied();
        for raw in &n.scan.paths {
            let Some(mut abs) = scopes[i].absolute(raw) else {
                continue;
            };
            // The longest prefix that is a file; the root file at worst (`crate::Foo` names lib.rs). A name
            // that file re-exports is followed to its source (a chain of re-exports, boundedly: a hostile
            // or cyclic chain stops at the last file reached).
            let mut hops = 0;
            let (k, to) = loop {
                let Some((k, to)) = (0..=abs.len())
                    .rev()
                    .find_map(|k| file_of(&abs[..k]).map(|t| (k, t)))
                else {
                    break (0, None);
                };
                let redirected = (k < abs.len() && hops < MAX_REEXPORT_HOPS)
                    .then(|| reexports.get(&(&n.unit, abs[..=k].to_vec())))
                    .flatten()
                    .filter(|source| **source != abs[..=k]);
                match redirected {
                    Some(source) => {
                        let mut next = source.clone();
                        next.extend(abs[k + 1..].iter().cloned());
                        abs = next;
                        hops += 1;
                    }
                    None => break (k, Some(to)),
                }
            };
            let Some(to) = to else {
                continue;
            };
            // A file's own enclosing modules are one unit with it (Rust shows a child its parent's private
            // items by design): a path up into an ancestor (`super::X`, `crate::parent::X` defined there) is
            // not an import between two files. Its parent's `use child::X` still is.
            let up_into_ancestor =
                nodes[to].module.len() < n.module.len() && n.module.starts_with(&nodes[to].module);
            if to != i && !up_into_ancestor {
                let name = abs.get(k).or(abs.last()).map_or("crate", String::as_str);
                edges.entry((i, to)).or_default().insert(name.to_string());
            }
        }
    }

    let mut adjacency = vec![Vec::new(); nodes.len()];
    for &(from, to) in edges.keys() {
        adjacency[from].push(to);
    }
    let mut found: Vec<Loop> = components(&adjacency)
        .into_iter()
        .filter(|c| c.len() > 1)
        .map(|c| {
            let inside: HashSet<usize> = c.iter().copied().collect();
            let mut files: Vec<String> = c.iter().map(|&i| nodes[i].rel.clone()).collect();
            files.sort();
            let mut ties: Vec<Tie> = edges
                .iter()
                .filter(|((from, to), _)| inside.contains(from) && inside.contains(to))
                .map(|(&(from, to), names)| Tie {
                    from: nodes[from].rel.clone(),
                    to: nodes[to].rel.clone(),
                    names: names.iter().cloned().collect(),
                })
                .collect();
            ties.sort_by(|a, b| (&a.from, &a.to).cmp(&(&b.from, &b.to)));
            Loop { files, ties }
        })
        .collect();
    found.sort_by(|a, b| a.files.cmp(&b.files));
    found
}

/// The module paths that are test-only in each unit: children declared under `#[cfg(test)]` and files that
/// open with `#![cfg(test)]`. Everything at or below them stays out of the graph: tests may use their parent
/// freely.
fn test_modules(nodes: &[Node]) -> HashSet<(Unit, Vec<String>)> {
    let mut tests = HashSet::new();
    for n in nodes {
        if n.scan.test_only {
            tests.insert((n.unit.clone(), n.module.clone()));
        }
        for c in n.scan.children.iter().filter(|c| c.test) {
            let path = n
                .module
                .iter()
                .chain(&c.inline)
                .chain([&c.name])
                .cloned()
                .collect();
            tests.insert((n.unit.clone(), path));
        }
    }
    tests
}

/// What a path's first segment can mean in one file: its module, the child modules it declares and the
/// modules it imported by name, each in the inline module (`mod name { }`) where it is declared.
struct Scope<'a> {
    module: &'a [String],
    children: HashSet<(&'a [String], &'a str)>,
    aliases: HashMap<(&'a [String], &'a str), Vec<String>>,
}

impl Scope<'_> {
    /// A path as a module path from the unit's root, or `None` when it leaves the crate (`std::`, `gonio_x::`,
    /// a leading `::`), starts at a local name that is neither a declared child nor an imported module, or
    /// climbs above the root.
    fn absolute(&self, raw: &RawPath) -> Option<Vec<String>> {
        let here = || self.module.iter().chain(&raw.inline).cloned().collect::<Vec<_>>();
        let first = raw.segs.first()?.as_str();
        let key = (&raw.inline[..], first);
        let (mut base, mut rest) = match first {
            "crate" => (Vec::new(), &raw.segs[1..]),
            "self" => (here(), &raw.segs[1..]),
            "super" => (here(), &raw.segs[..]),
            _ if self.children.contains(&key) => (here(), &raw.segs[..]),
            _ => (self.aliases.get(&key)?.clone(), &raw.segs[1..]),
        };
        while let Some((s, tail)) = rest.split_first()
            && s == "super"
        {
            base.pop()?;
            rest = tail;
        }
        base.extend(rest.iter().cloned());
        Some(base)
    }
}

/// Tarjan's strongly connected components of a graph given as adjacency lists.
fn components(adjacency: &[Vec<usize>]) -> Vec<Vec<usize>> {
    struct State<'a> {
        adjacency: &'a [Vec<usize>],
        index: Vec<Option<usize>>,
        low: Vec<usize>,
        on_stack: Vec<bool>,
        stack: Vec<usize>,
        next: usize,
        out: Vec<Vec<usize>>,
    }
    fn visit(s: &mut State<'_>, v: usize) {
        s.index[v] = Some(s.next);
        s.low[v] = s.next;
        s.next += 1;
        s.stack.push(v);
        s.on_stack[v] = true;
        for &w in &s.adjacency[v] {
            match s.index[w] {
                None => {
                    visit(s, w);
                    s.low[v] = s.low[v].min(s.low[w]);
                }
                Some(iw) if s.on_stack[w] => s.low[v] = s.low[v].min(iw),
                Some(_) => {}
            }
        }
        if Some(s.low[v]) == s.index[v] {
            let mut component = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack[w] = false;
                component.push(w);
                if w == v {
                    break;
                }
            }
            s.out.push(component);
        }
    }
    let n = adjacency.len();
    let mut s = State {
        adjacency,
        index: vec![None; n],
        low: vec![0; n],
        on_stack: vec![false; n],
        stack: Vec::new(),
        next: 0,
        out: Vec::new(),
    };
    for v in 0..n {
        if s.index[v].is_none() {
            visit(&mut s, v);
        }
    }
    s.out
}
