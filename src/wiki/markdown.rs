//! Markdown → HTML (pulldown-cmark, CommonMark + tables/strikethrough/task lists), then
//! sanitised with ammonia: no `<script>`, no event-handler attributes, no `javascript:` or
//! other active URL schemes, links get `rel="noopener noreferrer nofollow"`.

use std::collections::HashSet;

use pulldown_cmark::{Event, Options, Parser, TagEnd};

fn options() -> Options {
    Options::ENABLE_TABLES | Options::ENABLE_STRIKETHROUGH | Options::ENABLE_TASKLISTS
}

/// Renders Markdown to sanitised HTML, safe to embed in a page.
pub fn render(markdown: &str) -> String {
    let mut html = String::with_capacity(markdown.len() * 3 / 2);
    pulldown_cmark::html::push_html(&mut html, Parser::new_ext(markdown, options()));
    sanitize(&html)
}

/// Sanitises an HTML fragment with the wiki's allow-list.
pub fn sanitize(html: &str) -> String {
    let schemes: HashSet<&str> = ["http", "https", "mailto"].into_iter().collect();
    ammonia::Builder::default()
        .url_schemes(schemes)
        .link_rel(Some("noopener noreferrer nofollow"))
        .add_tag_attributes("td", &["align"])
        .add_tag_attributes("th", &["align"])
        .clean(html)
        .to_string()
}

/// The visible text of a Markdown document (for search and snippets): text and code, with
/// raw HTML dropped and blocks separated by newlines.
pub fn plain_text(markdown: &str) -> String {
    let mut out = String::with_capacity(markdown.len());
    for event in Parser::new_ext(markdown, options()) {
        match event {
            Event::Text(t) | Event::Code(t) => out.push_str(&t),
            Event::SoftBreak | Event::HardBreak => out.push(' '),
            Event::End(
                TagEnd::Paragraph
                | TagEnd::Heading(_)
                | TagEnd::Item
                | TagEnd::CodeBlock
                | TagEnd::TableCell
                | TagEnd::TableRow
                | TagEnd::BlockQuote(_),
            ) => out.push('\n'),
            _ => {}
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_scripts_handlers_and_javascript_urls() {
        let html = render(
            "# Hi\n\n<script>alert(1)</script>\n\n<img src=x onerror=alert(1)>\n\n\
             [x](javascript:alert(1)) <a href=\"javascript:alert(2)\" onclick=\"e()\">y</a>",
        );
        assert!(!html.contains("<script"), "{html}");
        assert!(!html.contains("onerror"), "{html}");
        assert!(!html.contains("onclick"), "{html}");
        assert!(!html.contains("javascript:"), "{html}");
        assert!(html.contains("<h1>Hi</h1>"), "{html}");
    }

    #[test]
    fn keeps_ordinary_markdown() {
        let html = render("*a* **b** `c`\n\n| x | y |\n|---|---|\n| 1 | 2 |\n\n[l](https://e.org)");
        assert!(html.contains("<em>a</em>"));
        assert!(html.contains("<table>"));
        assert!(html.contains("rel=\"noopener noreferrer nofollow\""));
    }

    #[test]
    fn plain_text_drops_markup() {
        let t = plain_text("# Title\n\nSome *bold* `code` <b>raw</b>");
        assert!(t.contains("Title"));
        assert!(t.contains("Some bold code"));
        assert!(!t.contains('<'));
    }
}
