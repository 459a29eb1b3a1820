//! Rust source to a flat token list with every comment and literal gone, so that a path written in a doc
//! comment, a string or a raw string can never look like an import. Not a full Rust lexer: only what the
//! path scan needs (identifiers, `::`, single punctuation), and total: any input, however malformed, gives
//! tokens (an unterminated comment or string simply runs to the end of the file).

#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Tok {
    Ident(String),
    /// `::`
    PathSep,
    Punct(char),
    /// A string, char or number literal, kept as a placeholder so that the tokens on either side of it do
    /// not become neighbours.
    Lit,
}

pub(crate) fn tokens(src: &str) -> Vec<Tok> {
    let c: Vec<char> = src.chars().collect();
    let at = |i: usize| c.get(i).copied().unwrap_or('\0');
    let mut out = Vec::new();
    let mut i = 0;
    while i < c.len() {
        let ch = c[i];
        if ch.is_whitespace() {
            i += 1;
        } else if ch == '/' && at(i + 1) == '/' {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if ch == '/' && at(i + 1) == '*' {
            i = block_comment_end(&c, i);
        } else if ch == '"' {
            i = string_end(&c, i + 1);
            out.push(Tok::Lit);
        } else if ch == '\'' {
            i = quote_end(&c, i);
            // A lifetime or label says nothing about paths, so only a char literal leaves a placeholder.
            if at(i - 1) == '\'' {
                out.push(Tok::Lit);
            }
        } else if ch.is_ascii_digit() {
            while i < c.len() && (c[i].is_alphanumeric() || c[i] == '_') {
                i += 1;
            }
            out.push(Tok::Lit);
        } else if ch.is_alphabetic() || ch == '_' {
            let start = i;
            while i < c.len() && (c[i].is_alphanumeric() || c[i] == '_') {
                i += 1;
            }
            let word: String = c[start..i].iter().collect();
            i = prefixed_literal(&c, i, &word, &mut out);
        } else if ch == ':' && at(i + 1) == ':' {
            out.push(Tok::PathSep);
            i += 2;
        } else {
            out.push(Tok::Punct(ch));
            i += 1;
        }
    }
    out
}

/// After a word that may prefix a literal (`b"..."`, `br#"..."#`, `c"..."`, `b'x'`) or a raw identifier
/// (`r#type`): consume that literal and return the index after it; otherwise push the word as an identifier.
fn prefixed_literal(c: &[char], i: usize, word: &str, out: &mut Vec<Tok>) -> usize {
    let at = |k: usize| c.get(k).copied().unwrap_or('\0');
    let raw = matches!(word, "r" | "br" | "cr");
    if matches!(word, "b" | "c") && at(i) == '"' {
        out.push(Tok::Lit);
        return string_end(c, i + 1);
    }
    if word == "b" && at(i) == '\'' {
        out.push(Tok::Lit);
        return quote_end(c, i);
    }
    if raw {
        let hashes = (i..c.len()).take_while(|&k| c[k] == '#').count();
        if at(i + hashes) == '"' {
            out.push(Tok::Lit);
            return raw_string_end(c, i + hashes + 1, hashes);
        }
        if word == "r" && hashes == 1 && (at(i + 1).is_alphabetic() || at(i + 1) == '_') {
            let start = i + 1;
            let mut k = start;
            while k < c.len() && (c[k].is_alphanumeric() || c[k] == '_') {
                k += 1;
            }
            out.push(Tok::Ident(c[start..k].iter().collect()));
            return k;
        }
    }
    out.push(Tok::Ident(word.to_string()));
    i
}

/// `i` at the `/` of `/*`; block comments nest in Rust.
fn block_comment_end(c: &[char], mut i: usize) -> usize {
    let mut depth = 0usize;
    while i < c.len() {
        if c[i] == '/' && c.get(i + 1) == Some(&'*') {
            depth += 1;
            i += 2;
        } else if c[i] == '*' && c.get(i + 1) == Some(&'/') {
            depth -= 1;
            i += 2;
            if depth == 0 {
                return i;
            }
        } else {
            i += 1;
        }
    }
    c.len()
}

/// `i` just after the opening `"`; returns the index after the closing one.
fn string_end(c: &[char], mut i: usize) -> usize {
    while i < c.len() {
        match c[i] {
            '\\' => i += 2,
            '"' => return i + 1,
            _ => i += 1,
        }
    }
    c.len()
}

/// `i` just after `r##"`; the string ends at a `"` followed by as many `#`.
fn raw_string_end(c: &[char], mut i: usize, hashes: usize) -> usize {
    while i < c.len() {
        if c[i] == '"' && (1..=hashes).all(|k| c.get(i + k) == Some(&'#')) {
            return i + 1 + hashes;
        }
        i += 1;
    }
    c.len()
}

/// `i` at a `'`: a char literal (`'a'`, `'\n'`, `'\u{7f}'`, `'"'`) ends after its closing quote, a lifetime or
/// label (`'a`, `'static`) after its name. The returned index is past a `'` only for a char literal.
fn quote_end(c: &[char], i: usize) -> usize {
    let at = |k: usize| c.get(k).copied().unwrap_or('\0');
    if at(i + 1) == '\\' {
        // Escapes are at most `\u{10FFFF}`: stop at the line's end so a stray quote cannot swallow the file.
        let mut k = i + 3;
        while k < c.len() && c[k] != '\'' && c[k] != '\n' {
            k += 1;
        }
        return (k + 1).min(c.len());
    }
    if at(i + 2) == '\'' {
        return i + 3;
    }
    let mut k = i + 1;
    while k < c.len() && (c[k].is_alphanumeric() || c[k] == '_') {
        k += 1;
    }
    k
}

#[cfg(test)]
mod tests {
    use super::*;

    fn idents(src: &str) -> Vec<String> {
        tokens(src)
            .into_iter()
            .filter_map(|t| match t {
                Tok::Ident(s) => Some(s),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn comments_and_literals_leave_no_identifiers() {
        let src = r###"
            // crate::leak1::X
            /// crate::leak2::Y
            //! crate::leak3
            /* outer /* nested crate::leak4 */ still comment crate::leak5 */
            let s = "crate::leak6 \" crate::leak7";
            let r = r#"crate::leak8 " crate::leak9"#;
            let b = br##"crate::leak10"# "##;
            let q = '"'; let e = '\''; let u = '\u{7f}'; let x = b'"'; let c = c"leak11";
            fn f<'a>(v: &'a str) -> &'static str { v }
        "###;
        let words = idents(src);
        assert!(
            !words.iter().any(|w| w.starts_with("leak")),
            "leaked from a comment or literal: {words:?}"
        );
        assert_eq!(
            words.iter().filter(|w| *w == "let").count(),
            8,
            "code after the literals is still read"
        );
        // Lifetimes go, the types beside them stay.
        assert!(!words.contains(&"static".to_string()) && words.contains(&"str".to_string()));
    }

    #[test]
    fn raw_identifiers_and_path_separators() {
        assert_eq!(
            tokens("r#type::x"),
            vec![Tok::Ident("type".into()), Tok::PathSep, Tok::Ident("x".into())]
        );
        assert_eq!(idents("1e5 0x_ff 2.5f64"), Vec::<String>::new());
    }

    #[test]
    fn unterminated_input_does_not_panic() {
        for src in ["\"abc", "/* open", "r##\"x\"#", "'", "'\\", "b'", "r#", "::", ":"] {
            let _ = tokens(src);
        }
    }
}
