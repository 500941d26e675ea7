//! Reading calibration YAML with a maintained parser (saphyr-parser, linear time) into the
//! few shapes calibration files use, and writing them back.
//!
//! ROS `camera_info` files and OpenCV `FileStorage` files are mappings of scalars, lists of
//! scalars and small nested mappings (`rows`, `cols`, `dt`, `data`). OpenCV's `%YAML:1.0`
//! header is not valid YAML 1.2, so that one line is blanked before parsing (line numbers
//! stay true); its `!!opencv-matrix` tags are valid YAML and ignored. What a calibration
//! never needs is refused with the line: a key given twice (the second would silently
//! replace the first), aliases, lists of lists, nesting deeper than
//! [`MAX_DEPTH`], more than one document, files over [`MAX_CALIBRATION_FILE`] bytes.

use std::collections::BTreeMap;

use saphyr_parser::{Event, Parser, Span, StrInput};

use crate::limits::MAX_CALIBRATION_FILE;

/// Deepest nesting of mappings a calibration file may use (the top level is 1).
pub const MAX_DEPTH: usize = 4;
/// A value in a calibration file.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// A scalar, unquoted.
    Scalar(String),
    /// A flow list of scalars.
    List(Vec<String>),
    /// A one-level mapping.
    Map(BTreeMap<String, Value>),
}

/// Why a file could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {what}")]
pub struct YamlError {
    /// 1-based line number.
    pub line: usize,
    /// What was wrong.
    pub what: String,
}

fn error(line: usize, what: impl Into<String>) -> YamlError {
    YamlError {
        line,
        what: what.into(),
    }
}

/// Parse the file: top-level keys and their values.
pub fn parse(text: &str) -> Result<BTreeMap<String, Value>, YamlError> {
    if text.len() as u64 > MAX_CALIBRATION_FILE {
        return Err(error(
            1,
            format!(
                "{} bytes is more than a calibration file holds (at most {MAX_CALIBRATION_FILE})",
                text.len()
            ),
        ));
    }
    let text = without_opencv_header(text);
    let mut events = Events {
        parser: Parser::new_from_str(text),
    };
    let mut top = BTreeMap::new();
    let mut documents = 0;
    loop {
        let (event, span) = events.next()?;
        match event {
            Event::StreamStart | Event::DocumentEnd | Event::Nothing => {}
            Event::StreamEnd => return Ok(top),
            Event::DocumentStart(_) => {
                documents += 1;
                if documents > 1 {
                    return Err(error(
                        line(&span),
                        "a second document: a calibration file holds one",
                    ));
                }
            }
            Event::MappingStart(..) => top = events.mapping(1)?,
            Event::Scalar(s, ..) if s.is_empty() => {}
            _ => {
                return Err(error(
                    line(&span),
                    "expected `key: value` lines at the top level",
                ));
            }
        }
    }
}

/// `text` with OpenCV's `%YAML:1.0` directive line blanked (it is not YAML 1.2); other
/// lines untouched so that line numbers in errors stay true.
fn without_opencv_header(text: &str) -> &str {
    let first = text.lines().next().unwrap_or("");
    if first.trim_start().starts_with("%YAML:") {
        &text[first.len()..]
    } else {
        text
    }
}

fn line(span: &Span) -> usize {
    span.start.line()
}

/// The parser's events with errors in our terms.
struct Events<'a> {
    parser: Parser<'a, StrInput<'a>>,
}

impl<'a> Events<'a> {
    fn next(&mut self) -> Result<(Event<'a>, Span), YamlError> {
        match self.parser.next() {
            Some(Ok(e)) => Ok(e),
            Some(Err(e)) => Err(error(e.marker().line(), e.info())),
            None => Err(error(0, "unexpected end of the file")),
        }
    }

    /// The entries of a mapping whose start was just read, at nesting `depth`.
    fn mapping(&mut self, depth: usize) -> Result<BTreeMap<String, Value>, YamlError> {
        let mut map = BTreeMap::new();
        loop {
            let (event, span) = self.next()?;
            let key = match event {
                Event::MappingEnd => return Ok(map),
                Event::Scalar(key, ..) => key.into_owned(),
                _ => return Err(error(line(&span), "keys must be plain names")),
            };
            let (event, span) = self.next()?;
            let value = self.value(event, &span, &key, depth)?;
            if map.insert(key.clone(), value).is_some() {
                return Err(error(
                    line(&span),
                    format!("`{key}` is given twice (the second would silently replace the first)"),
                ));
            }
        }
    }

    /// The value that `event` starts, for `key`.
    fn value(
        &mut self,
        event: Event<'a>,
        span: &Span,
        key: &str,
        depth: usize,
    ) -> Result<Value, YamlError> {
        match event {
            Event::Scalar(s, ..) => Ok(Value::Scalar(s.into_owned())),
            Event::SequenceStart(..) => self.list(key),
            Event::MappingStart(..) if depth < MAX_DEPTH => {
                Ok(Value::Map(self.mapping(depth + 1)?))
            }
            Event::MappingStart(..) => Err(error(
                line(span),
                format!("`{key}` nests deeper than {MAX_DEPTH} levels"),
            )),
            Event::Alias(_) => Err(error(
                line(span),
                format!("`{key}`: aliases (*name) are not used in calibration files"),
            )),
            _ => Err(error(line(span), format!("`{key}` has no value"))),
        }
    }

    /// The scalars of a list whose start was just read.
    fn list(&mut self, key: &str) -> Result<Value, YamlError> {
        let mut items = Vec::new();
        loop {
            let (event, span) = self.next()?;
            match event {
                Event::SequenceEnd => return Ok(Value::List(items)),
                Event::Scalar(s, ..) => items.push(s.into_owned()),
                _ => {
                    return Err(error(
                        line(&span),
                        format!("`{key}`: a list may hold only numbers or words"),
                    ));
                }
            }
        }
    }
}

/// One OpenCV `FileStorage` matrix entry (row-major `data`).
pub fn opencv_matrix(name: &str, rows: usize, cols: usize, data: &[f64]) -> String {
    format!(
        "{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: {}\n",
        list(data)
    )
}

/// Format numbers so they read back exactly.
pub fn list(values: &[f64]) -> String {
    let items: Vec<String> = values.iter().map(|v| format!("{v:?}")).collect();
    format!("[{}]", items.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_opencv_filestorage_with_header_tags_and_wrapped_lists() {
        let text = "%YAML:1.0\n---\nimage_width: 640\nK1: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0.,\n       500., 240., 0., 0., 1. ]\n# comment\nname: \"left # not a comment\"\n";
        let y = parse(text).unwrap();
        assert_eq!(y["image_width"], Value::Scalar("640".into()));
        let Value::Map(k) = &y["K1"] else { panic!() };
        assert_eq!(k["rows"], Value::Scalar("3".into()));
        let Value::List(data) = &k["data"] else {
            panic!()
        };
        assert_eq!(data.len(), 9);
        assert_eq!(data[4], "500.");
        assert_eq!(y["name"], Value::Scalar("left # not a comment".into()));
    }

    #[test]
    fn says_which_line_is_wrong() {
        let e = parse("a: 1\nthis is not yaml\n").unwrap_err();
        assert!((2..=3).contains(&e.line), "{e}");
        let e = parse("a: [1, 2,\n").unwrap_err();
        assert!(e.line >= 1, "{e}");
        let e = parse("a: 1\nb: [1, [2]]\n").unwrap_err();
        assert_eq!(e.line, 2, "{e}");
        assert!(e.what.contains("only numbers"), "{e}");
    }

    #[test]
    fn a_key_given_twice_is_refused_at_its_second_line() {
        let e = parse("T: [1, 0, 0]\nR: [1]\nT: [2, 0, 0]\n").unwrap_err();
        assert_eq!(e.line, 3, "{e}");
        assert!(e.what.contains("`T` is given twice"), "{e}");
        let e = parse("K1:\n  rows: 3\n  rows: 4\n").unwrap_err();
        assert!(e.what.contains("`rows` is given twice"), "{e}");
    }

    #[test]
    fn aliases_deep_nesting_and_second_documents_are_refused() {
        let e = parse("a: &x [1, 2]\nb: *x\n").unwrap_err();
        assert!(e.what.contains("aliases"), "{e}");
        let e = parse("a: {b: {c: {d: {e: 1}}}}\n").unwrap_err();
        assert!(e.what.contains("deeper"), "{e}");
        let e = parse("a: 1\n---\nb: 2\n").unwrap_err();
        assert!(e.what.contains("second document"), "{e}");
        assert!(parse("").unwrap().is_empty());
        assert!(parse("- 1\n- 2\n").is_err());
    }

    #[test]
    fn huge_and_unterminated_lists_end_in_an_error_not_a_hang() {
        // Over the size bound: refused before parsing.
        let big = format!("a: [{}]\n", "1, ".repeat(400_000));
        let e = parse(&big).unwrap_err();
        assert!(e.what.contains("more than a calibration file"), "{e}");
        // Under it but never closed: the linear parser reaches the end and says so.
        let open = format!("a: [{}\n", "1, ".repeat(300_000));
        assert!(parse(&open).is_err());
        // A long list that is well formed reads in full.
        let long = format!("a: [{}1]\n", "1, ".repeat(300_000));
        let Value::List(items) = &parse(&long).unwrap()["a"] else {
            panic!()
        };
        assert_eq!(items.len(), 300_001);
    }

    proptest::proptest! {
        /// Any text, and any damage to a real calibration file, gives a value or an
        /// error with a line, never a panic.
        #[test]
        fn any_text_parses_or_errors(text in "\\PC{0,300}", cut in 0usize..3000, junk in "[\\[\\]{}:,&*!%# -]{0,8}") {
            let _ = parse(&text);
            let good = format!(
                "%YAML:1.0\n---\nimage_width: 640\n{}T: {}\nname: \"a # b\"\n",
                opencv_matrix("K1", 3, 3, &[500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0]),
                list(&[-14.0, 0.0, 0.0]),
            );
            let at = good.floor_char_boundary(cut.min(good.len()));
            let damaged = format!("{}{junk}{}", &good[..at], &good[at..]);
            if let Err(e) = parse(&damaged) {
                proptest::prop_assert!(e.line <= damaged.lines().count() + 1, "{}", e);
            }
        }
    }
}
