//! The report as a list of blocks, written twice: Markdown (`report.md`, for a repository or
//! an issue) and a self-contained HTML page (`report.html`, for a browser) that shows the same
//! tables and the plots beside them.

use std::fmt::Write as _;

/// One block of the report.
#[derive(Clone, Debug, PartialEq)]
pub enum Block {
    /// A heading of level 1–3.
    Heading(u8, String),
    /// A paragraph (`code` in backticks is kept as code).
    Para(String),
    /// A table: its header and rows of cells.
    Table {
        /// Column titles.
        head: Vec<String>,
        /// Rows of cells.
        rows: Vec<Vec<String>>,
    },
    /// A bulleted list.
    List(Vec<String>),
    /// Images side by side (alt text, file in the report's directory).
    Images(Vec<(String, String)>),
}

/// The blocks as Markdown.
pub fn markdown(blocks: &[Block]) -> String {
    let mut md = String::new();
    for b in blocks {
        match b {
            Block::Heading(level, text) => {
                let _ = writeln!(md, "{} {text}\n", "#".repeat(usize::from(*level)));
            }
            Block::Para(text) => {
                let _ = writeln!(md, "{text}\n");
            }
            Block::Table { head, rows } => {
                let _ = writeln!(md, "| {} |", head.join(" | "));
                let _ = writeln!(md, "|{}", "---|".repeat(head.len()));
                for row in rows {
                    let _ = writeln!(md, "| {} |", row.join(" | "));
                }
                md.push('\n');
            }
            Block::List(items) => {
                for i in items {
                    let _ = writeln!(md, "- {i}");
                }
                md.push('\n');
            }
            Block::Images(images) => {
                let line: Vec<String> = images
                    .iter()
                    .map(|(alt, file)| format!("![{alt}]({file})"))
                    .collect();
                let _ = writeln!(md, "{}\n", line.join(" "));
            }
        }
    }
    md
}

/// `text` escaped for HTML, with `code` spans kept as code.
fn inline(text: &str) -> String {
    let escaped = text
        .replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;");
    let mut out = String::new();
    for (i, part) in escaped.split('`').enumerate() {
        if i % 2 == 1 {
            let _ = write!(out, "<code>{part}</code>");
        } else {
            out.push_str(part);
        }
    }
    out
}

/// The blocks as one HTML page titled `title` (no script, no resource outside the report's
/// directory).
pub fn html(title: &str, blocks: &[Block]) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>{}</title><style>\
         body{{font-family:sans-serif;max-width:75em;margin:1em auto;padding:0 1em;color:#222}}\
         table{{border-collapse:collapse;margin:0.5em 0 1em}}\
         td,th{{border:1px solid #bbb;padding:0.2em 0.5em;text-align:left;vertical-align:top}}\
         th{{background:#eee}} code{{background:#f3f3f3;padding:0 0.2em}}\
         .plots{{display:flex;flex-wrap:wrap;gap:0.5em}} .plots img{{width:32em;max-width:100%}}\
         </style></head><body>\n",
        inline(title)
    );
    for b in blocks {
        match b {
            Block::Heading(level, text) => {
                let _ = writeln!(h, "<h{level}>{}</h{level}>", inline(text));
            }
            Block::Para(text) => {
                let _ = writeln!(h, "<p>{}</p>", inline(text));
            }
            Block::Table { head, rows } => {
                h.push_str("<table><tr>");
                for c in head {
                    let _ = write!(h, "<th>{}</th>", inline(c));
                }
                h.push_str("</tr>\n");
                for row in rows {
                    h.push_str("<tr>");
                    for c in row {
                        let _ = write!(h, "<td>{}</td>", inline(c));
                    }
                    h.push_str("</tr>\n");
                }
                h.push_str("</table>\n");
            }
            Block::List(items) => {
                h.push_str("<ul>");
                for i in items {
                    let _ = write!(h, "<li>{}</li>", inline(i));
                }
                h.push_str("</ul>\n");
            }
            Block::Images(images) => {
                h.push_str("<div class=\"plots\">");
                for (alt, file) in images {
                    let _ = write!(
                        h,
                        "<a href=\"{0}\"><img src=\"{0}\" alt=\"{1}\"></a>",
                        inline(file),
                        inline(alt)
                    );
                }
                h.push_str("</div>\n");
            }
        }
    }
    h.push_str("</body></html>\n");
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_renderings_hold_every_block() {
        let blocks = vec![
            Block::Heading(1, "Model-gap report".into()),
            Block::Para("a <b> & `x^2`".into()),
            Block::Table {
                head: vec!["a".into(), "b".into()],
                rows: vec![vec!["1".into(), "2".into()]],
            },
            Block::List(vec!["one".into()]),
            Block::Images(vec![("map".into(), "map_force_x.svg".into())]),
        ];
        let md = markdown(&blocks);
        assert!(md.contains("# Model-gap report") && md.contains("| 1 | 2 |"));
        assert!(md.contains("![map](map_force_x.svg)") && md.contains("- one"));
        let h = html("t", &blocks);
        assert!(h.contains("a &lt;b&gt; &amp; <code>x^2</code>"), "{h}");
        assert!(h.contains("<img src=\"map_force_x.svg\"") && h.contains("<td>2</td>"));
    }
}
