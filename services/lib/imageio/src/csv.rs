//! Reading the commands' CSV inputs: a fixed header, then rows of that many comma-separated
//! fields. Every problem names the file, the line and the column.

use std::path::Path;

/// One data row: its line number (1-based) and its fields, trimmed.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub line: usize,
    pub fields: Vec<String>,
}

/// A named problem in a CSV file.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct CsvError {
    pub file: String,
    pub message: String,
}

/// Reads `path`, checks that its header is exactly `header` (spaces around names allowed),
/// and returns the data rows (blank lines and lines starting with `#` skipped).
pub fn read(path: &Path, header: &[&str]) -> Result<Vec<Row>, CsvError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| CsvError {
        file: file.clone(),
        message: format!("cannot read: {e}"),
    })?;
    parse(&text, header).map_err(|message| CsvError { file, message })
}

/// [`read`] on text already in memory; the error is the message without the file name.
pub fn parse(text: &str, header: &[&str]) -> Result<Vec<Row>, String> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (hline, hdr) = lines
        .next()
        .ok_or_else(|| format!("empty: expected the header {}", header.join(",")))?;
    let got: Vec<&str> = hdr.split(',').map(str::trim).collect();
    if got != header {
        return Err(format!(
            "line {}: the header must be {} (got {})",
            hline + 1,
            header.join(","),
            got.join(",")
        ));
    }
    let mut rows = Vec::new();
    for (i, l) in lines {
        let fields: Vec<String> = l.split(',').map(|f| f.trim().to_string()).collect();
        if fields.len() != header.len() {
            return Err(format!(
                "line {}: expected {} columns ({}), got {}",
                i + 1,
                header.len(),
                header.join(","),
                fields.len()
            ));
        }
        rows.push(Row {
            line: i + 1,
            fields,
        });
    }
    if rows.is_empty() {
        return Err("no data rows after the header".into());
    }
    Ok(rows)
}

impl Row {
    /// Field `k` (named `name` in messages) as a finite number.
    pub fn number(&self, k: usize, name: &str) -> Result<f64, String> {
        let f = &self.fields[k];
        match f.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(v) => Err(format!(
                "line {}: column {name} is {v}, not a finite number",
                self.line
            )),
            Err(_) => Err(format!(
                "line {}: column {name} is {f:?}, not a number",
                self.line
            )),
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
        assert!(
            rows[1]
                .number(1, "b")
                .unwrap_err()
                .contains("line 5: column b is \"x\"")
        );
        assert!(
            parse("a,c\n1,2\n", &["a", "b"])
                .unwrap_err()
                .contains("header must be a,b")
        );
        assert!(
            parse("a,b\n1,2,3\n", &["a", "b"])
                .unwrap_err()
                .contains("line 2: expected 2 columns")
        );
        assert!(
            parse("a,b\n", &["a", "b"])
                .unwrap_err()
                .contains("no data rows")
        );
        assert!(parse("", &["a", "b"]).unwrap_err().contains("empty"));
        let nan = parse("a,b\nNaN,1\n", &["a", "b"]).unwrap();
        assert!(
            nan[0]
                .number(0, "a")
                .unwrap_err()
                .contains("not a finite number")
        );
    }
}
