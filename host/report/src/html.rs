//! One self-contained HTML page per run: images embedded as data URIs, inline CSS, no
//! JavaScript and nothing fetched, so the file can be mailed, archived or opened
//! offline years later.

use std::fmt::Write as _;
use std::path::Path;

use base64::Engine as _;

/// A report page being assembled.
pub struct Page {
    title: String,
    body: String,
}

/// One line of a key–value table. `id` marks the value cell (`id="…"`), so tests and
/// scripts can find a number in the page.
pub struct Row {
    /// What the value is.
    pub key: String,
    /// The value, with its unit and uncertainty.
    pub value: String,
    /// Element id of the value cell.
    pub id: Option<&'static str>,
}

impl Row {
    /// A row without an id.
    pub fn new(key: impl Into<String>, value: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            value: value.into(),
            id: None,
        }
    }

    /// A row whose value cell has `id`.
    pub fn with_id(id: &'static str, key: impl Into<String>, value: impl Into<String>) -> Self {
        Self {
            id: Some(id),
            ..Self::new(key, value)
        }
    }
}

const STYLE: &str = "body{font-family:'DejaVu Sans',Helvetica,Arial,sans-serif;max-width:1000px;margin:2em auto;padding:0 1em;color:#222;line-height:1.45}\
h1{font-size:1.6em;border-bottom:2px solid #0072b2;padding-bottom:.2em}\
h2{font-size:1.2em;margin-top:1.8em;color:#0072b2}\
table{border-collapse:collapse;margin:.5em 0}\
td,th{border:1px solid #ddd;padding:.25em .7em;text-align:left;vertical-align:top}\
th{background:#f3f6f9}td.num{font-family:'DejaVu Sans Mono',monospace}\
pre{background:#f5f5f5;border:1px solid #ddd;padding:.6em;overflow-x:auto;white-space:pre-wrap}\
.warn{background:#fff4e0;border-left:4px solid #e69f00;padding:.4em .8em;margin:.4em 0}\
.ok{background:#e8f6f0;border-left:4px solid #009e73;padding:.4em .8em;margin:.4em 0}\
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}\
figcaption{font-size:.9em;color:#555}.pair{display:flex;gap:1em;flex-wrap:wrap}\
.pair figure{flex:1 1 300px}.scaled img{width:100%;image-rendering:pixelated}footer{margin-top:3em;font-size:.8em;color:#777}";

impl Page {
    /// A page titled `title`.
    pub fn new(title: &str) -> Self {
        let mut body = String::new();
        let _ = writeln!(body, "<h1>{}</h1>", escape(title));
        Self {
            title: title.to_string(),
            body,
        }
    }

    /// A section heading.
    pub fn heading(&mut self, text: &str) {
        let _ = writeln!(self.body, "<h2>{}</h2>", escape(text));
    }

    /// A paragraph of plain text.
    pub fn paragraph(&mut self, text: &str) {
        let _ = writeln!(self.body, "<p>{}</p>", escape(text));
    }

    /// A command line to copy.
    pub fn command(&mut self, command: &str) {
        let _ = writeln!(self.body, "<pre><code>{}</code></pre>", escape(command));
    }

    /// A key–value table.
    pub fn table(&mut self, rows: &[Row]) {
        self.body.push_str("<table>\n");
        for r in rows {
            let id = r.id.map(|i| format!(" id=\"{i}\"")).unwrap_or_default();
            let _ = writeln!(
                self.body,
                "<tr><th>{}</th><td class=\"num\"{id}>{}</td></tr>",
                escape(&r.key),
                escape(&r.value)
            );
        }
        self.body.push_str("</table>\n");
    }

    /// A table with a header row.
    pub fn grid(&mut self, header: &[&str], rows: &[Vec<String>]) {
        self.body.push_str("<table>\n<tr>");
        for h in header {
            let _ = write!(self.body, "<th>{}</th>", escape(h));
        }
        self.body.push_str("</tr>\n");
        for row in rows {
            self.body.push_str("<tr>");
            for cell in row {
                let _ = write!(self.body, "<td class=\"num\">{}</td>", escape(cell));
            }
            self.body.push_str("</tr>\n");
        }
        self.body.push_str("</table>\n");
    }

    /// The warnings, or a line saying there are none.
    pub fn warnings(&mut self, warnings: &[String]) {
        if warnings.is_empty() {
            self.body
                .push_str("<div class=\"ok\" id=\"no-warnings\">No warnings.</div>\n");
        }
        for w in warnings {
            let _ = writeln!(self.body, "<div class=\"warn\">⚠ {}</div>", escape(w));
        }
    }

    /// A PNG figure, embedded, with a caption and optional links to the files on disk
    /// (relative to the page).
    pub fn figure(&mut self, png: &[u8], alt: &str, caption: &str, files: &[&str]) {
        self.body.push_str(&figure_html(png, alt, caption, files));
    }

    /// Several PNG figures side by side.
    pub fn figures(&mut self, figures: &[(&[u8], &str, &str)]) {
        self.body.push_str("<div class=\"pair\">\n");
        for (png, alt, caption) in figures {
            self.body.push_str(&figure_html(png, alt, caption, &[]));
        }
        self.body.push_str("</div>\n");
    }

    /// Several PNG figures side by side, each drawn as wide as its column with its
    /// pixels kept square and sharp: camera-sized images (a 128² DPC phase) that
    /// would otherwise be thumbnails.
    pub fn figures_scaled(&mut self, figures: &[(&[u8], &str, &str)]) {
        self.body.push_str("<div class=\"pair scaled\">\n");
        for (png, alt, caption) in figures {
            self.body.push_str(&figure_html(png, alt, caption, &[]));
        }
        self.body.push_str("</div>\n");
    }

    /// A list of links to files beside the page (`(relative path, what it is)`).
    pub fn files(&mut self, files: &[(String, String)]) {
        self.body.push_str("<ul>\n");
        for (path, what) in files {
            let _ = writeln!(
                self.body,
                "<li><a href=\"{}\">{}</a>: {}</li>",
                escape(path),
                escape(path),
                escape(what)
            );
        }
        self.body.push_str("</ul>\n");
    }

    /// The whole document.
    pub fn finish(self) -> String {
        format!(
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
             <meta name=\"generator\" content=\"fpm {version}\">\n<title>{title}</title>\n\
             <style>{STYLE}</style>\n</head>\n<body>\n{body}<footer>Written by fpm {version} \
             (self-contained: no scripts, nothing fetched).</footer>\n</body>\n</html>\n",
            version = env!("CARGO_PKG_VERSION"),
            title = escape(&self.title),
            body = self.body
        )
    }

    /// Write the document to `path`.
    pub fn write(self, path: &Path) -> anyhow::Result<()> {
        use anyhow::Context as _;
        std::fs::write(path, self.finish()).with_context(|| format!("writing {}", path.display()))
    }
}

fn figure_html(png: &[u8], alt: &str, caption: &str, files: &[&str]) -> String {
    let data = base64::engine::general_purpose::STANDARD.encode(png);
    let links = if files.is_empty() {
        String::new()
    } else {
        let list: Vec<String> = files
            .iter()
            .map(|f| format!("<a href=\"{0}\">{0}</a>", escape(f)))
            .collect();
        format!(" Files: {}.", list.join(", "))
    };
    format!(
        "<figure><img src=\"data:image/png;base64,{data}\" alt=\"{}\"><figcaption>{}{links}</figcaption></figure>\n",
        escape(alt),
        escape(caption)
    )
}

/// `text` with HTML's special characters escaped.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
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

/// This process's command line, quoted for a POSIX shell, to reproduce the run.
pub fn command_line() -> String {
    let mut args = std::env::args();
    let program = args.next().map(|p| {
        Path::new(&p)
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or(p)
    });
    program
        .into_iter()
        .chain(args)
        .map(|a| shell_quote(&a))
        .collect::<Vec<_>>()
        .join(" ")
}

/// `arg` quoted for a POSIX shell where it needs it.
pub fn shell_quote(arg: &str) -> String {
    let plain = !arg.is_empty()
        && arg
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=:,+@%".contains(c));
    if plain {
        arg.to_string()
    } else {
        format!("'{}'", arg.replace('\'', "'\\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_escaped_and_the_page_stands_alone() {
        let mut p = Page::new("a <b> & c");
        p.table(&[Row::with_id("dx", "Δx", "+0.5 ± 0.1 mm")]);
        p.warnings(&["only \"3\" LEDs".into()]);
        p.figure(&[1, 2, 3], "alt", "cap", &["plots/x.svg"]);
        let html = p.finish();
        assert!(html.contains("<title>a &lt;b&gt; &amp; c</title>"));
        assert!(html.contains("id=\"dx\">+0.5 ± 0.1 mm<"));
        assert!(html.contains("only &quot;3&quot; LEDs"));
        assert!(html.contains("src=\"data:image/png;base64,AQID\""));
        assert!(!html.contains("<script") && !html.contains("http"));
    }

    #[test]
    fn arguments_are_quoted_only_where_a_shell_needs_it() {
        assert_eq!(shell_quote("--out"), "--out");
        assert_eq!(shell_quote("/tmp/a b"), "'/tmp/a b'");
        assert_eq!(shell_quote("it's"), "'it'\\''s'");
        assert_eq!(shell_quote(""), "''");
    }
}
