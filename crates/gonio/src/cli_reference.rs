//! The command-line reference (docs/reference/cli.md), generated from the parser itself, and the checks that
//! keep the documentation true to the parser: the reference is not stale, every `gonio` command line the
//! documents quote parses, and no relative link of theirs is dead.
//!
//! Regenerate the reference after changing a command: `GONIO_BLESS=1 cargo test -p gonio --bin gonio
//! cli_reference`.

use std::fmt::Write as _;

use clap::CommandFactory;

/// The reference's text: each command's `--help`, depth first, in the parser's order.
pub fn markdown() -> String {
    let mut out = String::from(
        "# Command-line reference\n\n\
         Generated from the parser (`crates/gonio/src/cli_reference.rs`; a test fails when this page is stale). \
         Every command also prints its part with `--help`. Units: degrees, nanometres, seconds, millimetres, \
         watts; BRDF values in 1/sr.\n",
    );
    let mut root = crate::Cli::command().term_width(110);
    root.build();
    section(&mut out, &mut root, "gonio", 2);
    out
}

fn section(out: &mut String, command: &mut clap::Command, path: &str, depth: usize) {
    let _ = write!(out, "\n{} `{path}`\n\n```text\n", "#".repeat(depth.min(4)));
    let help = command.render_long_help().to_string();
    for line in help.lines() {
        let _ = writeln!(out, "{}", line.trim_end());
    }
    out.push_str("```\n");
    let names: Vec<String> = command
        .get_subcommands()
        .filter(|c| !c.is_hide_set() && c.get_name() != "help")
        .map(|c| c.get_name().to_string())
        .collect();
    for name in names {
        if let Some(sub) = command.find_subcommand_mut(&name) {
            section(out, sub, &format!("{path} {name}"), depth + 1);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::path::{Path, PathBuf};

    use clap::{CommandFactory, Parser};

    fn root() -> PathBuf {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        root.canonicalize().unwrap_or(root)
    }

    /// README.md and every Markdown page under docs/.
    fn documents() -> Vec<PathBuf> {
        fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
            let Ok(entries) = std::fs::read_dir(dir) else {
                return;
            };
            for e in entries.flatten() {
                let p = e.path();
                if p.is_dir() {
                    walk(&p, out);
                } else if p.extension().is_some_and(|x| x == "md") {
                    out.push(p);
                }
            }
        }
        let mut out = vec![root().join("README.md")];
        walk(&root().join("docs"), &mut out);
        out.sort();
        out
    }

    #[test]
    fn the_reference_is_the_parsers() {
        let path = root().join("docs/reference/cli.md");
        let now = super::markdown();
        if std::env::var_os("GONIO_BLESS").is_some() {
            std::fs::write(&path, &now).expect("write docs/reference/cli.md");
            return;
        }
        let stored = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(
            stored == now,
            "docs/reference/cli.md is stale: regenerate it with `GONIO_BLESS=1 cargo test -p gonio --bin gonio \
             cli_reference`"
        );
    }

    /// How a document quotes `gonio`: a command line (a line of a ```sh block) or a mention in running text (an
    /// inline code span, which may name a command or an option without its values).
    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Quote {
        CommandLine,
        Mention,
    }

    /// The `gonio ...` a document quotes, each with its line. Synopses (with `[`, `<`, `|` or `...`) are
    /// neither and are left out, as is what follows a `#` comment in a shell line.
    fn quoted_commands(text: &str) -> Vec<(usize, Quote, String)> {
        let mut out = Vec::new();
        let mut in_sh = false;
        for (n, line) in text.lines().enumerate() {
            let trimmed = line.trim_start();
            if trimmed.starts_with("```") {
                in_sh = !in_sh && (trimmed == "```sh" || trimmed == "```bash" || trimmed == "```console");
                continue;
            }
            let candidates: Vec<(Quote, String)> = if in_sh {
                let code = trimmed.trim_start_matches("$ ");
                vec![(
                    Quote::CommandLine,
                    code.split(" #").next().unwrap_or("").to_string(),
                )]
            } else {
                line.split('`')
                    .skip(1)
                    .step_by(2)
                    .map(|s| (Quote::Mention, s.to_string()))
                    .collect()
            };
            for (quote, c) in candidates {
                // A command after `&&` or `;` in a shell line.
                for part in c.split("&&").flat_map(|p| p.split(';')) {
                    let part = part.trim();
                    if (part == "gonio" || part.starts_with("gonio "))
                        && !["[", "<", "|", "...", "…"].iter().any(|s| part.contains(s))
                    {
                        out.push((n + 1, quote, part.to_string()));
                    }
                }
            }
        }
        out
    }

    /// A mention names commands that exist and options each of them has.
    fn check_mention(words: &[String]) -> Result<(), String> {
        let mut command = crate::Cli::command();
        command.build();
        let mut rest = words.iter().skip(1);
        let mut path = String::from("gonio");
        for word in rest.by_ref() {
            if let Some(sub) = command.find_subcommand(word) {
                path = format!("{path} {word}");
                let sub = sub.clone();
                command = sub;
                continue;
            }
            check_option(&command, &path, word)?;
            break;
        }
        for word in rest {
            check_option(&command, &path, word)?;
        }
        Ok(())
    }

    fn check_option(command: &clap::Command, path: &str, word: &str) -> Result<(), String> {
        let Some(long) = word.strip_prefix("--") else {
            return Ok(());
        };
        let long = long.split('=').next().unwrap_or("");
        let known = long == "help" || command.get_arguments().any(|a| a.get_long() == Some(long));
        if known {
            Ok(())
        } else {
            Err(format!("`{path}` has no option --{long}"))
        }
    }

    #[test]
    fn every_quoted_command_line_parses() {
        let mut failures = Vec::new();
        let mut lines = 0;
        for doc in documents() {
            let text = std::fs::read_to_string(&doc).expect("read document");
            for (line, quote, command) in quoted_commands(&text) {
                let Some(words) = shlex::split(&command) else {
                    failures.push(format!("{}:{line}: cannot split `{command}`", doc.display()));
                    continue;
                };
                let result = match quote {
                    Quote::CommandLine => {
                        lines += 1;
                        crate::Cli::try_parse_from(&words)
                            .map(drop)
                            .map_err(|e| e.to_string().lines().next().unwrap_or("").to_string())
                    }
                    Quote::Mention => check_mention(&words),
                };
                if let Err(e) = result {
                    failures.push(format!("{}:{line}: `{command}`: {e}", doc.display()));
                }
            }
        }
        assert!(
            lines >= 10,
            "only {lines} command lines found: is the scan broken?"
        );
        assert!(
            failures.is_empty(),
            "quoted commands that do not parse:\n{}",
            failures.join("\n")
        );
    }

    #[test]
    fn no_relative_link_is_dead() {
        let mut dead = Vec::new();
        for doc in documents() {
            let text = std::fs::read_to_string(&doc).expect("read document");
            let dir = doc.parent().expect("a document's directory");
            for (n, line) in text.lines().enumerate() {
                // Markdown links and images: ](target) with a relative target.
                for piece in line.split("](").skip(1) {
                    let Some(target) = piece.split(')').next() else {
                        continue;
                    };
                    let target = target.split('#').next().unwrap_or("").trim();
                    if target.is_empty() || target.contains("://") || target.starts_with("mailto:") {
                        continue;
                    }
                    if !dir.join(target).exists() {
                        dead.push(format!("{}:{}: {target}", doc.display(), n + 1));
                    }
                }
            }
        }
        assert!(dead.is_empty(), "dead links:\n{}", dead.join("\n"));
    }

    /// The ```toml blocks of a document.
    fn toml_blocks(text: &str) -> Vec<String> {
        let mut blocks = Vec::new();
        let mut current: Option<String> = None;
        for line in text.lines() {
            match (&mut current, line.trim_start()) {
                (None, "```toml") => current = Some(String::new()),
                (Some(_), "```") => blocks.extend(current.take()),
                (Some(b), _) => {
                    b.push_str(line);
                    b.push('\n');
                }
                (None, _) => {}
            }
        }
        blocks
    }

    /// The instrument files the documents show (a lab's header and devices, the tutorial's rehearsal devices) are
    /// read by the instrument file's own parser, with the rest of the simulated instrument file around them.
    #[test]
    fn the_documents_instrument_examples_parse() {
        let simulated = gonio_instrument::SIMULATED_INSTRUMENT_TOML;
        // The simulated file from its first axis on: what the examples leave out.
        let axes_on = &simulated[simulated.find("[[instrument.axes]]").expect("axes")..];
        let mut checked = 0;
        for page in ["docs/reference/instrument-file.md", "docs/tutorial.md"] {
            let text = std::fs::read_to_string(root().join(page)).expect("read the page");
            for block in toml_blocks(&text)
                .into_iter()
                .filter(|b| b.contains("[[instrument.devices]]"))
            {
                let head = if block.contains("[instrument]") {
                    String::new()
                } else {
                    "[instrument]\nname = \"example\"\ngeometry = \"reference\"\n\n".to_string()
                };
                let file = format!("{head}{block}\n{axes_on}");
                if let Err(e) = gonio_instrument::InstrumentFile::parse(&file, page) {
                    panic!("{page}: the example does not parse: {e}\n{block}");
                }
                checked += 1;
            }
        }
        assert_eq!(checked, 2, "the two examples were not found");
    }

    #[test]
    fn the_scan_finds_commands_in_blocks_and_spans_and_skips_synopses() {
        let text = "Run `gonio plan a.toml` first.\n```sh\ngonio run a.toml --out x  # comment\n```\n\
                    Synopsis: `gonio run CAMPAIGN [--out DIR]`.\n`cargo build && gonio devices`\n";
        let found: Vec<(Quote, String)> = quoted_commands(text)
            .into_iter()
            .map(|(_, q, c)| (q, c))
            .collect();
        let expected = [
            (Quote::Mention, "gonio plan a.toml"),
            (Quote::CommandLine, "gonio run a.toml --out x"),
            (Quote::Mention, "gonio devices"),
        ];
        assert_eq!(found, expected.map(|(q, c)| (q, c.to_string())));
        // A mention may leave out values, not invent options or commands.
        let words = |s: &str| shlex::split(s).expect("split");
        assert!(check_mention(&words("gonio run --instrument")).is_ok());
        assert!(check_mention(&words("gonio ctl move --geometry 30,0,30,180")).is_ok());
        assert!(check_mention(&words("gonio run --no-such-option")).is_err());
        assert!(check_mention(&words("gonio ctl --instrument x")).is_err());
    }
}
