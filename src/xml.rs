//! The XML of GDAL's side files (a VRT, a PAM `.aux.xml`) as a small tree
//! (element name, attributes, text, children), built with quick-xml. Such
//! files are a few kilobytes to a few megabytes, so holding the tree is cheap
//! and the checks read as plain lookups.

use quick_xml::events::{BytesStart, Event};
use quick_xml::reader::Reader;

/// One element: attributes in file order, its own text (trimmed), children.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Element {
    pub name: String,
    pub attrs: Vec<(String, String)>,
    pub text: String,
    pub children: Vec<Element>,
}

impl Element {
    pub fn attr(&self, name: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }

    /// The first child named `name`.
    pub fn child(&self, name: &str) -> Option<&Element> {
        self.children.iter().find(|c| c.name == name)
    }

    pub fn children_named<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Element> {
        self.children.iter().filter(move |c| c.name == name)
    }
}

fn start(e: &BytesStart) -> Result<Element, String> {
    let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
    let mut attrs = Vec::new();
    for a in e.attributes() {
        let a = a.map_err(|err| format!("<{name}>: {err}"))?;
        let key = String::from_utf8_lossy(a.key.as_ref()).into_owned();
        let value = a
            .unescape_value()
            .map_err(|err| format!("<{name} {key}>: {err}"))?
            .into_owned();
        attrs.push((key, value));
    }
    Ok(Element {
        name,
        attrs,
        ..Default::default()
    })
}

/// Parse a whole document into its root element; one-line errors.
pub fn parse(text: &str) -> Result<Element, String> {
    let mut reader = Reader::from_str(text);
    reader.config_mut().trim_text(true);
    let mut stack: Vec<Element> = Vec::new();
    let mut root: Option<Element> = None;
    loop {
        let event = reader
            .read_event()
            .map_err(|e| format!("at byte {}: {e}", reader.error_position()))?;
        match event {
            Event::Start(e) => stack.push(start(&e)?),
            Event::Empty(e) => {
                let el = start(&e)?;
                match stack.last_mut() {
                    Some(parent) => parent.children.push(el),
                    None => root = root.or(Some(el)),
                }
            }
            Event::End(_) => {
                let el = stack.pop().ok_or("unbalanced end tag")?;
                match stack.last_mut() {
                    Some(parent) => parent.children.push(el),
                    None => root = root.or(Some(el)),
                }
            }
            Event::Text(t) => {
                let s = t.unescape().map_err(|e| e.to_string())?;
                if let Some(el) = stack.last_mut() {
                    el.text.push_str(&s);
                }
            }
            Event::CData(c) => {
                if let Some(el) = stack.last_mut() {
                    el.text.push_str(&String::from_utf8_lossy(&c));
                }
            }
            Event::Eof => break,
            _ => {} // declaration, comments, processing instructions, doctype
        }
    }
    if let Some(open) = stack.last() {
        return Err(format!("<{}> is never closed", open.name));
    }
    root.ok_or_else(|| "no element".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tree_with_attributes_text_and_entities() {
        let doc = r#"<?xml version="1.0"?>
            <!-- a comment -->
            <A x="1" y="a&amp;b"><B>t &lt; 2</B><C/><B>second</B></A>"#;
        let a = parse(doc).unwrap();
        assert_eq!(a.name, "A");
        assert_eq!(a.attr("y"), Some("a&b"));
        assert_eq!(a.child("B").unwrap().text, "t < 2");
        assert_eq!(a.children_named("B").count(), 2);
        assert_eq!(a.children[1].name, "C");
        assert!(parse("<A><B></A>").is_err());
        assert!(parse("").is_err());
    }
}
