//! The little HTML the report needs: escaping, tables, numbers with their units. Hand-written because it is
//! a handful of elements with no input from a browser: every text that came from a file or a device goes
//! through [`esc`].

use std::fmt::Write as _;

/// Text as HTML character data or a double-quoted attribute value.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// A number with `digits` significant digits, or an en dash for a missing or non-finite one.
pub fn num(v: Option<f64>, digits: usize) -> String {
    match v.filter(|v| v.is_finite()) {
        None => "&ndash;".into(),
        Some(0.0) => "0".into(),
        Some(v) => {
            let magnitude = v.abs().log10().floor();
            if (-3.0..5.0).contains(&magnitude) {
                let decimals = (digits as f64 - 1.0 - magnitude).max(0.0) as usize;
                format!("{v:.decimals$}")
            } else {
                format!("{v:.prec$e}", prec = digits.saturating_sub(1))
            }
        }
    }
}

/// A fraction as a percentage with `digits` significant digits (so that 0.004 % does not read as 0.00 %).
pub fn pct(v: Option<f64>, digits: usize) -> String {
    match v.filter(|v| v.is_finite()) {
        None => "&ndash;".into(),
        Some(v) => format!("{} %", num(Some(v * 100.0), digits)),
    }
}

/// An angle in degrees as a person writes it: at most two decimals, no trailing zeros.
pub fn deg(v: f64) -> String {
    let r = (v * 100.0).round() / 100.0;
    format!("{}", r + 0.0)
}

/// A table: a header row and rows of cells that are already HTML (escape text with [`esc`] first).
pub fn table(class: &str, header: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = format!("<table class=\"{}\"><thead><tr>", esc(class));
    for h in header {
        let _ = write!(s, "<th>{}</th>", esc(h));
    }
    s.push_str("</tr></thead><tbody>");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{c}</td>");
        }
        s.push_str("</tr>");
    }
    s.push_str("</tbody></table>");
    s
}

/// A two-column table of names and values (values already HTML).
pub fn facts(rows: &[(&str, String)]) -> String {
    let mut s = String::from("<table class=\"facts\"><tbody>");
    for (k, v) in rows {
        let _ = write!(s, "<tr><th>{}</th><td>{v}</td></tr>", esc(k));
    }
    s.push_str("</tbody></table>");
    s
}

/// A paragraph of plain text.
pub fn p(text: &str) -> String {
    format!("<p>{}</p>", esc(text))
}

/// A note that something is absent or limited, set apart from the data.
pub fn note(text: &str) -> String {
    format!("<p class=\"note\">{}</p>", esc(text))
}

/// A figure: an inline SVG and its caption.
pub fn figure(id: &str, svg: &str, caption: &str) -> String {
    // The SVG's XML prolog has no place inside HTML.
    let body = match svg.find("<svg") {
        Some(i) => &svg[i..],
        None => svg,
    };
    format!(
        "<figure id=\"{}\">{body}<figcaption>{}</figcaption></figure>",
        esc(id),
        esc(caption)
    )
}

/// A file's text, folded away, with its name.
pub fn folded_text(summary: &str, text: &str) -> String {
    format!(
        "<details><summary>{}</summary><pre>{}</pre></details>",
        esc(summary),
        esc(text)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_escaped_and_numbers_keep_their_digits() {
        assert_eq!(esc("<a href=\"x\">&'"), "&lt;a href=&quot;x&quot;&gt;&amp;&#39;");
        assert_eq!(num(Some(0.123456), 3), "0.123");
        assert_eq!(num(Some(1234.6), 3), "1235");
        assert_eq!(num(Some(1.5e-7), 3), "1.50e-7");
        assert_eq!(num(Some(f64::NAN), 3), "&ndash;");
        assert_eq!(num(None, 3), "&ndash;");
        assert_eq!(pct(Some(0.0512), 2), "5.1 %");
        assert_eq!(pct(Some(4.2e-5), 2), "0.0042 %");
        assert_eq!(deg(14.999999999999998), "15");
        assert_eq!(deg(-0.0), "0");
        let t = table("x", &["a<b"], &[vec!["1".into()]]);
        assert!(t.contains("<th>a&lt;b</th>") && t.contains("<td>1</td>"), "{t}");
        let f = figure("f", "<?xml version=\"1.0\"?><svg></svg>", "c");
        assert!(f.starts_with("<figure id=\"f\"><svg>"), "{f}");
    }
}
