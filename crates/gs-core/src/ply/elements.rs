//! Any PLY file's header as elements of scalar properties, read strictly: `format` version 1.0,
//! no property named twice in an element, counts that are numbers; and the check that a binary
//! body holds exactly what the header announces, no more and no less. For the formats read by
//! element (SuperSplat's compressed PLY, VeGaS's models) before any value is taken from them.

/// A PLY element: its name, count and property names with their byte sizes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Element {
    /// The element's name (`vertex`, `chunk`, `time`...).
    pub name: String,
    /// Its number of rows.
    pub count: usize,
    /// Its properties in file order: name and size in bytes.
    pub properties: Vec<(String, usize)>,
}

impl Element {
    /// Bytes a row takes.
    pub fn stride(&self) -> usize {
        self.properties.iter().map(|p| p.1).sum()
    }

    /// The byte offset of property `name` in a row, with its size.
    pub fn offset(&self, name: &str) -> Option<(usize, usize)> {
        let mut at = 0;
        for (p, size) in &self.properties {
            if p == name {
                return Some((at, *size));
            }
            at += size;
        }
        None
    }
}

/// A header: the body's format, the elements in order and where the body starts.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Header {
    /// `binary_little_endian`, `binary_big_endian` or `ascii`.
    pub format: String,
    /// The elements, in file order.
    pub elements: Vec<Element>,
    /// The byte where the body starts.
    pub body_start: usize,
}

/// The header of `bytes`; an error names the line and what is wrong with it (list properties
/// are refused: none of the formats read this way has them).
pub fn parse_elements(bytes: &[u8]) -> Result<Header, String> {
    if !bytes.starts_with(b"ply") {
        return Err("not a PLY file (it does not start with \"ply\")".into());
    }
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or("no end_header line")?;
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| "the header is not text")?;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (number, line) in text.lines().enumerate() {
        let words: Vec<&str> = line.split_whitespace().collect();
        let bad = |why: &str| format!("header line {} {line:?}: {why}", number + 1);
        match words.as_slice() {
            ["ply"] | [] => {}
            ["comment", ..] | ["obj_info", ..] => {}
            ["format", kind @ ("binary_little_endian" | "binary_big_endian" | "ascii"), "1.0"] => {
                if format.replace(kind.to_string()).is_some() {
                    return Err(bad("a second format line"));
                }
            }
            ["format", ..] => return Err(bad("only format 1.0, binary or ascii, is read")),
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count.parse().map_err(|_| bad("not a count"))?,
                properties: Vec::new(),
            }),
            ["property", ty, name] => {
                let size = match *ty {
                    "char" | "uchar" | "int8" | "uint8" => 1,
                    "short" | "ushort" | "int16" | "uint16" => 2,
                    "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
                    "double" | "float64" => 8,
                    _ => return Err(bad("unknown property type")),
                };
                let element = elements
                    .last_mut()
                    .ok_or_else(|| bad("a property before any element"))?;
                if element.properties.iter().any(|p| p.0 == *name) {
                    return Err(bad("a property named twice"));
                }
                element.properties.push((name.to_string(), size));
            }
            _ => return Err(bad("not a line of a PLY header of scalar properties")),
        }
    }
    let mut names = std::collections::HashSet::new();
    if let Some(e) = elements.iter().find(|e| !names.insert(e.name.as_str())) {
        return Err(format!("element {} is named twice", e.name));
    }
    Ok(Header {
        format: format.ok_or("no format line")?,
        elements,
        body_start: end + 11,
    })
}

/// Checks that the binary body of `bytes` holds exactly the rows `header` announces: a count
/// that is too small (rows read from the next element's bytes), too large, or trailing bytes
/// are refused. Returns where each element's rows start (an ascii body is not measured: its
/// starts are all the body's).
pub fn check_body_length(header: &Header, bytes: &[u8]) -> Result<Vec<usize>, String> {
    if header.format == "ascii" {
        return Ok(vec![header.body_start; header.elements.len()]);
    }
    let mut starts = Vec::with_capacity(header.elements.len());
    let mut expected = header.body_start;
    for e in &header.elements {
        starts.push(expected);
        expected = e
            .count
            .checked_mul(e.stride())
            .and_then(|s| s.checked_add(expected))
            .ok_or_else(|| format!("element {}: {} rows cannot be held", e.name, e.count))?;
    }
    match bytes.len().cmp(&expected) {
        std::cmp::Ordering::Equal => Ok(starts),
        std::cmp::Ordering::Less => Err(format!(
            "the body is {} bytes; the header announces {} ({})",
            bytes.len() - header.body_start,
            expected - header.body_start,
            header
                .elements
                .iter()
                .map(|e| format!("{} {} of {} bytes", e.count, e.name, e.stride()))
                .collect::<Vec<_>>()
                .join(", ")
        )),
        std::cmp::Ordering::Greater => Err(format!(
            "{} bytes after the last element the header announces",
            bytes.len() - expected
        )),
    }
}
