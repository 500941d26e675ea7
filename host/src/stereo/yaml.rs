//! The YAML subset that camera calibration files use, read and written by hand.
//!
//! ROS `camera_info` files and OpenCV `FileStorage` files are flat: top-level keys with a
//! scalar, or a one-level mapping (`rows`, `cols`, `dt`, `data`) whose `data` is a flow
//! list that may span lines. OpenCV's `%YAML:1.0` header and `!!opencv-matrix` tags are
//! not valid YAML 1.2 and trip general parsers, so this reader takes exactly that subset
//! and says which line it could not read.

use std::collections::BTreeMap;

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

/// Strip a comment (not inside quotes) and trailing space.
fn strip_comment(line: &str) -> &str {
    let mut quoted = None;
    for (i, c) in line.char_indices() {
        match (c, quoted) {
            ('"' | '\'', None) => quoted = Some(c),
            (q, Some(open)) if q == open => quoted = None,
            ('#', None) if i == 0 || line[..i].ends_with(' ') => return line[..i].trim_end(),
            _ => {}
        }
    }
    line.trim_end()
}

fn unquote(s: &str) -> String {
    let s = s.trim();
    let quoted = s.len() >= 2
        && ((s.starts_with('"') && s.ends_with('"')) || (s.starts_with('\'') && s.ends_with('\'')));
    if quoted {
        s[1..s.len() - 1].to_string()
    } else {
        s.to_string()
    }
}

/// Drop a leading `!!tag` or `!tag` from a value.
fn strip_tag(s: &str) -> &str {
    let s = s.trim();
    if s.starts_with('!') {
        s.split_once(' ').map_or("", |(_, rest)| rest.trim())
    } else {
        s
    }
}

/// Parse the file: top-level keys and their values.
pub fn parse(text: &str) -> Result<BTreeMap<String, Value>, YamlError> {
    let lines: Vec<(usize, &str)> = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, strip_comment(l)))
        .filter(|(_, l)| !l.trim().is_empty())
        .filter(|(_, l)| !l.starts_with('%') && l.trim() != "---" && l.trim() != "...")
        .collect();
    let mut top = BTreeMap::new();
    let mut i = 0;
    while i < lines.len() {
        let (n, line) = lines[i];
        if line.starts_with(' ') || line.starts_with('\t') {
            return Err(error(n, "unexpected indentation"));
        }
        let (key, rest) = line
            .split_once(':')
            .ok_or_else(|| error(n, format!("expected `key: value`, found {line:?}")))?;
        let key = unquote(key);
        let rest = strip_tag(rest);
        i += 1;
        let value = if rest.is_empty() {
            // A nested mapping: the indented lines that follow.
            let mut map = BTreeMap::new();
            while i < lines.len() && lines[i].1.starts_with([' ', '\t']) {
                let (m, inner) = lines[i];
                let (k, v) = inner
                    .trim()
                    .split_once(':')
                    .ok_or_else(|| error(m, format!("expected `key: value`, found {inner:?}")))?;
                i += 1;
                let (value, used) = value_of(strip_tag(v), &lines[i..], m)?;
                i += used;
                map.insert(unquote(k), value);
            }
            if map.is_empty() {
                return Err(error(n, format!("`{key}` has no value")));
            }
            Value::Map(map)
        } else {
            let (value, used) = value_of(rest, &lines[i..], n)?;
            i += used;
            value
        };
        top.insert(key, value);
    }
    Ok(top)
}

/// A scalar, or a flow list that may continue on the following lines; returns the value
/// and how many following lines it used.
fn value_of(first: &str, rest: &[(usize, &str)], n: usize) -> Result<(Value, usize), YamlError> {
    if !first.starts_with('[') {
        return Ok((Value::Scalar(unquote(first)), 0));
    }
    let mut text = first.to_string();
    let mut used = 0;
    while !text.contains(']') {
        let (_, next) = rest
            .get(used)
            .ok_or_else(|| error(n, "unterminated list"))?;
        text.push(' ');
        text.push_str(next.trim());
        used += 1;
    }
    let inner = text.trim_start_matches('[');
    let (inner, after) = inner.split_once(']').expect("checked above");
    if !after.trim().is_empty() {
        return Err(error(n, format!("unexpected {after:?} after a list")));
    }
    let items = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(unquote)
        .collect();
    Ok((Value::List(items), used))
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
        assert_eq!(e.line, 2);
        let e = parse("a: [1, 2,\n").unwrap_err();
        assert!(e.what.contains("unterminated"), "{e}");
        assert_eq!(parse("  b: 1\n").unwrap_err().line, 1);
    }
}
