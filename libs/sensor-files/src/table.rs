//! A delimited text file as a table: the header (if any) and the data rows with their line
//! numbers, laid out as the layout's `[table]` says.

use std::path::{Path, PathBuf};

use crate::error::{Error, read_text};
use crate::layout::{Column, Delimiter, TableLayout};

/// One data row: its 1-based line in the file and its cells (trimmed).
#[derive(Debug, Clone)]
pub struct Row {
    pub line: usize,
    pub cells: Vec<String>,
}

/// A file's table.
#[derive(Debug, Clone)]
pub struct Table {
    pub path: PathBuf,
    /// Column names, when the layout says there is a header row.
    pub header: Option<Vec<String>>,
    pub rows: Vec<Row>,
    /// The decimal separator numbers use.
    pub decimal: char,
    /// The lines before the header row (or the first data row), comments included: where
    /// exporters write the device and the rate.
    pub preamble: Vec<String>,
}

impl Table {
    /// Reads `path` as `layout` describes.
    pub fn read(path: &Path, layout: &TableLayout) -> Result<Table, Error> {
        let text = read_text(path)?;
        Table::parse(&text, path, layout)
    }

    /// Parses `text`; `path` names it in errors and picks an automatic delimiter.
    pub fn parse(text: &str, path: &Path, layout: &TableLayout) -> Result<Table, Error> {
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l))
            .skip(layout.skip_lines);
        if let Some(marker) = &layout.skip_until {
            let found = lines.by_ref().any(|(_, l)| l.trim() == marker);
            if !found {
                return Err(Error::file(
                    path,
                    format!("no line reads '{marker}' (skip_until)"),
                ));
            }
        }
        let is_content = |l: &str| {
            !l.trim().is_empty()
                && layout
                    .comment
                    .as_ref()
                    .is_none_or(|c| !l.trim_start().starts_with(c.as_str()))
        };
        let mut lines = lines.filter(|(_, l)| is_content(l)).peekable();
        if let Some(start) = &layout.header_starts_with {
            while lines
                .next_if(|(_, l)| !l.trim_start().starts_with(start.as_str()))
                .is_some()
            {}
            if lines.peek().is_none() {
                return Err(Error::file(
                    path,
                    format!("no header line starts with '{start}'"),
                ));
            }
        }
        let (first_line, first) = lines.peek().map_or((0, ""), |(n, l)| (*n, *l));
        // Everything above the header (or the first row), comments and skipped lines included.
        let preamble: Vec<String> = text
            .lines()
            .take(first_line.saturating_sub(1).min(PREAMBLE_LINES))
            .map(str::to_owned)
            .collect();
        let delimiter = resolve_delimiter(layout.delimiter, path, first)?;
        let header = if layout.header {
            let Some((n, line)) = lines.next() else {
                return Err(Error::file(path, "no header row: the file has no content"));
            };
            Some(split(line, delimiter, path, n)?)
        } else {
            None
        };
        let rows = lines
            .map(|(line, l)| split(l, delimiter, path, line).map(|cells| Row { line, cells }))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Table {
            path: path.to_owned(),
            header,
            rows,
            decimal: layout.decimal,
            preamble,
        })
    }

    /// The 0-based index of `column`, or an error naming the file and the columns it has.
    pub fn index(&self, column: &Column) -> Result<usize, Error> {
        match (column, &self.header) {
            (Column::Number(n), _) => Ok(n.saturating_sub(1)),
            (Column::Name(name), Some(header)) => {
                header.iter().position(|h| h == name).ok_or_else(|| {
                    Error::file(
                        &self.path,
                        format!("no column '{name}' (columns: {})", list(header)),
                    )
                })
            }
            (Column::Name(name), None) => Err(Error::file(
                &self.path,
                format!("column '{name}' needs a header row"),
            )),
        }
    }

    /// Whether the file has a column named `column` (numbers: always).
    pub fn has(&self, column: &Column) -> bool {
        match (column, &self.header) {
            (Column::Name(name), Some(header)) => header.iter().any(|h| h == name),
            (Column::Name(_), None) => false,
            (Column::Number(_), _) => true,
        }
    }
}

/// The header's names, shortened for a message.
fn list(header: &[String]) -> String {
    const SHOWN: usize = 24;
    let mut names: Vec<String> = header
        .iter()
        .take(SHOWN)
        .map(|h| format!("'{h}'"))
        .collect();
    if header.len() > SHOWN {
        names.push(format!("... {} more", header.len() - SHOWN));
    }
    names.join(", ")
}

/// Preamble lines kept at most (a file of comments only must not be copied whole).
const PREAMBLE_LINES: usize = 64;

/// The delimiter to split with: the layout's; by extension for `auto`; from the first line (the
/// header) for `detect`.
fn resolve_delimiter(delimiter: Delimiter, path: &Path, first: &str) -> Result<Delimiter, Error> {
    match delimiter {
        Delimiter::Auto => {}
        Delimiter::Detect => {
            let found = [
                ('\t', Delimiter::Tab),
                (';', Delimiter::Semicolon),
                (',', Delimiter::Comma),
            ]
            .into_iter()
            .find(|(c, _)| first.contains(*c));
            return Ok(found.map_or(Delimiter::Space, |(_, d)| d));
        }
        other => return Ok(other),
    }
    let ext = crate::plain_extension(path).to_ascii_lowercase();
    match ext.as_str() {
        "csv" => Ok(Delimiter::Comma),
        "tsv" | "tab" | "sto" | "mot" | "txt" => Ok(Delimiter::Tab),
        _ => Err(Error::file(
            path,
            format!(
                "cannot tell the delimiter from the extension '{ext}': set [table] delimiter (comma, tab, semicolon or whitespace)"
            ),
        )),
    }
}

/// The trimmed cells of one line. Lines with quotes go through the csv crate, so a quoted cell
/// (with the delimiter inside) reads as one cell.
fn split(line: &str, delimiter: Delimiter, path: &Path, n: usize) -> Result<Vec<String>, Error> {
    let byte = match delimiter {
        Delimiter::Whitespace => {
            return Ok(line.split_whitespace().map(str::to_owned).collect());
        }
        Delimiter::Comma | Delimiter::Auto | Delimiter::Detect => b',',
        Delimiter::Space => b' ',
        Delimiter::Tab => b'\t',
        Delimiter::Semicolon => b';',
    };
    if !line.contains('"') {
        return Ok(line
            .split(byte as char)
            .map(|c| c.trim().to_owned())
            .collect());
    }
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .delimiter(byte)
        .flexible(true)
        .from_reader(line.as_bytes());
    let mut record = csv::StringRecord::new();
    match reader.read_record(&mut record) {
        Ok(_) => Ok(record.iter().map(|c| c.trim().to_owned()).collect()),
        Err(e) => Err(Error::line(
            path,
            n,
            format!("cannot split the line into cells: {e}"),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> TableLayout {
        TableLayout::default()
    }

    #[test]
    fn header_search_comments_and_blank_lines() {
        let text = "sep=,\nDeviceTag:,x,,\n\nPacketCounter,SampleTimeFine,Acc_X\n# note\n1,10,0.5\n\n2,20,\"0.6\"\n";
        let l = TableLayout {
            header_starts_with: Some("PacketCounter".into()),
            comment: Some("#".into()),
            ..layout()
        };
        let t = Table::parse(text, Path::new("a.csv"), &l).unwrap();
        assert_eq!(t.header.as_deref().unwrap()[2], "Acc_X");
        assert_eq!(t.rows.len(), 2);
        assert_eq!((t.rows[0].line, t.rows[1].line), (6, 8));
        assert_eq!(t.rows[1].cells, ["2", "20", "0.6"]);
    }

    #[test]
    fn skip_until_and_tab_by_extension() {
        let text = "DataRate=100\nendheader\ntime\tpelvis_imu\n0\t1,0,0,0\n";
        let l = TableLayout {
            skip_until: Some("endheader".into()),
            ..layout()
        };
        let t = Table::parse(text, Path::new("x.sto"), &l).unwrap();
        assert_eq!(t.header.unwrap(), ["time", "pelvis_imu"]);
        assert_eq!(t.rows[0].cells, ["0", "1,0,0,0"]);
        assert_eq!(t.rows[0].line, 4);
    }

    #[test]
    fn whitespace_and_unknown_extensions() {
        let l = TableLayout {
            delimiter: Delimiter::Whitespace,
            header: false,
            ..layout()
        };
        let t = Table::parse("1  2\t3\n", Path::new("x.dat"), &l).unwrap();
        assert_eq!(t.rows[0].cells, ["1", "2", "3"]);
        let e = Table::parse("1,2\n", Path::new("x.dat"), &layout()).unwrap_err();
        assert!(
            e.to_string().contains("x.dat") && e.to_string().contains("delimiter"),
            "{e}"
        );
    }

    #[test]
    fn missing_columns_are_named_with_the_ones_there_are() {
        let t = Table::parse("a,b\n1,2\n", Path::new("x.csv"), &layout()).unwrap();
        let e = t.index(&Column::Name("c".into())).unwrap_err().to_string();
        assert!(
            e.contains("x.csv") && e.contains("'c'") && e.contains("'a', 'b'"),
            "{e}"
        );
        assert_eq!(t.index(&Column::Number(2)).unwrap(), 1);
    }
}
