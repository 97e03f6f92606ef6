//! Reading the commands' CSV inputs: a fixed header, then rows of that many comma-separated
//! fields. Every problem names the file, the line and the column.

use std::path::Path;

/// One data row: its line number (1-based) and its fields, trimmed.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub line: usize,
    pub fields: Vec<String>,
}

/// What is wrong with a CSV input, and where (1-based lines).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CsvProblem {
    #[error("cannot read: {0}")]
    Read(String),
    #[error("empty: expected the header {expected}")]
    Empty { expected: String },
    #[error("line {line}: the header must be {expected} (got {got})")]
    Header {
        line: usize,
        expected: String,
        got: String,
    },
    #[error("line {line}: expected {expected} columns ({header}), got {got}")]
    Columns {
        line: usize,
        expected: usize,
        header: String,
        got: usize,
    },
    #[error("no data rows after the header")]
    NoRows,
    #[error("line {line}: column {column} is {value:?}, not a number")]
    NotANumber {
        line: usize,
        column: String,
        value: String,
    },
    #[error("line {line}: column {column} is {value}, not a finite number")]
    NotFinite {
        line: usize,
        column: String,
        value: f64,
    },
}

/// A problem in a named CSV file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}: {problem}")]
pub struct CsvError {
    pub file: String,
    pub problem: CsvProblem,
}

/// Reads `path`, checks that its header is exactly `header` (spaces around names allowed),
/// and returns the data rows (blank lines and lines starting with `#` skipped).
pub fn read(path: &Path, header: &[&str]) -> Result<Vec<Row>, CsvError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| CsvError {
        file: file.clone(),
        problem: CsvProblem::Read(e.to_string()),
    })?;
    parse(&text, header).map_err(|problem| CsvError { file, problem })
}

/// [`read`] on text already in memory.
pub fn parse(text: &str, header: &[&str]) -> Result<Vec<Row>, CsvProblem> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (hline, hdr) = lines.next().ok_or_else(|| CsvProblem::Empty {
        expected: header.join(","),
    })?;
    let got: Vec<&str> = hdr.split(',').map(str::trim).collect();
    if got != header {
        return Err(CsvProblem::Header {
            line: hline + 1,
            expected: header.join(","),
            got: got.join(","),
        });
    }
    let mut rows = Vec::new();
    for (i, l) in lines {
        let fields: Vec<String> = l.split(',').map(|f| f.trim().to_string()).collect();
        if fields.len() != header.len() {
            return Err(CsvProblem::Columns {
                line: i + 1,
                expected: header.len(),
                header: header.join(","),
                got: fields.len(),
            });
        }
        rows.push(Row {
            line: i + 1,
            fields,
        });
    }
    if rows.is_empty() {
        return Err(CsvProblem::NoRows);
    }
    Ok(rows)
}

impl Row {
    /// Field `k` (named `name` in messages) as a finite number.
    pub fn number(&self, k: usize, name: &str) -> Result<f64, CsvProblem> {
        let f = self.fields.get(k).map(String::as_str).unwrap_or("");
        match f.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(value) => Err(CsvProblem::NotFinite {
                line: self.line,
                column: name.to_string(),
                value,
            }),
            Err(_) => Err(CsvProblem::NotANumber {
                line: self.line,
                column: name.to_string(),
                value: f.to_string(),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_columns_and_numbers_are_checked() {
        let rows = parse("a, b\n# comment\n1,2\n\n3, x\n", &["a", "b"]).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1].line, 5);
        assert_eq!(rows[0].number(1, "b").unwrap(), 2.0);
        let e = rows[1].number(1, "b").unwrap_err();
        assert!(matches!(e, CsvProblem::NotANumber { line: 5, .. }), "{e}");
        assert!(e.to_string().contains("line 5: column b is \"x\""));
        assert!(matches!(
            parse("a,c\n1,2\n", &["a", "b"]),
            Err(CsvProblem::Header { line: 1, .. })
        ));
        assert!(matches!(
            parse("a,b\n1,2,3\n", &["a", "b"]),
            Err(CsvProblem::Columns {
                line: 2,
                expected: 2,
                got: 3,
                ..
            })
        ));
        assert_eq!(parse("a,b\n", &["a", "b"]), Err(CsvProblem::NoRows));
        assert!(matches!(
            parse("", &["a", "b"]),
            Err(CsvProblem::Empty { .. })
        ));
        let nan = parse("a,b\nNaN,1\n", &["a", "b"]).unwrap();
        assert!(matches!(
            nan[0].number(0, "a"),
            Err(CsvProblem::NotFinite { line: 2, .. })
        ));
    }
}
