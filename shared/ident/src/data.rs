//! Measured data as columns of equal length, from a CSV with a header row.
//! Every defect names the file, the line and the column.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{path}: cannot read: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{path}: the file is empty (no header row)")]
    Empty { path: PathBuf },
    #[error("{path}: no data rows after the header")]
    NoRows { path: PathBuf },
    #[error("{path}: missing column `{column}` (the header has: {have})")]
    MissingColumn {
        path: PathBuf,
        column: String,
        have: String,
    },
    #[error("{path}:{line}: {found} fields where the header has {expected} (a truncated or malformed row)")]
    FieldCount {
        path: PathBuf,
        line: u64,
        found: usize,
        expected: usize,
    },
    #[error("{path}:{line}: column `{column}`: `{text}` is not a number")]
    NotANumber {
        path: PathBuf,
        line: u64,
        column: String,
        text: String,
    },
    #[error("{path}:{line}: column `{column}` is {value} (NaN and infinity are not data)")]
    NotFinite {
        path: PathBuf,
        line: u64,
        column: String,
        value: f64,
    },
    #[error("{path}:{line}: column `t` does not increase ({previous} then {value})")]
    TimeNotIncreasing {
        path: PathBuf,
        line: u64,
        previous: f64,
        value: f64,
    },
    #[error("{path}:{line}: {message}")]
    Csv { path: PathBuf, line: u64, message: String },
    #[error("{path}: no rows between {from_s} s and {to_s} s of the record (it spans {span_s:.1} s)")]
    EmptyWindow {
        path: PathBuf,
        from_s: f64,
        to_s: f64,
        span_s: f64,
    },
}

/// Columns by name, all of the same length, `t` strictly increasing.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    pub source: PathBuf,
    columns: BTreeMap<String, Vec<f64>>,
    len: usize,
}

impl Dataset {
    /// Reads a CSV. Every column named in `required` must be present; any
    /// column that is present is read, and must hold finite numbers in
    /// every row (an empty field reads as missing, NaN, in columns not
    /// required, such as `torque_ref` in position-only runs).
    pub fn from_csv(path: &Path, required: &[&str]) -> Result<Self, DataError> {
        let text = std::fs::read_to_string(path).map_err(|source| DataError::Read {
            path: path.to_owned(),
            source,
        })?;
        Self::parse_csv(&text, path, required)
    }

    /// As [`Dataset::from_csv`], from text; `path` only names the source.
    pub(crate) fn parse_csv(text: &str, path: &Path, required: &[&str]) -> Result<Self, DataError> {
        let p = || path.to_owned();
        if text.trim().is_empty() {
            return Err(DataError::Empty { path: p() });
        }
        let mut reader = csv::ReaderBuilder::new()
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(text.as_bytes());
        let header: Vec<String> = reader
            .headers()
            .map_err(|e| DataError::Csv {
                path: p(),
                line: 1,
                message: e.to_string(),
            })?
            .iter()
            .map(str::to_owned)
            .collect();
        for column in required {
            if !header.iter().any(|h| h == column) {
                return Err(DataError::MissingColumn {
                    path: p(),
                    column: (*column).to_owned(),
                    have: header.join(","),
                });
            }
        }
        let mut columns: Vec<Vec<f64>> = vec![Vec::new(); header.len()];
        for record in reader.records() {
            let record = record.map_err(|e| DataError::Csv {
                path: p(),
                line: e.position().map_or(0, |pos| pos.line()),
                message: e.to_string(),
            })?;
            let line = record.position().map_or(0, |pos| pos.line());
            if record.len() != header.len() {
                return Err(DataError::FieldCount {
                    path: p(),
                    line,
                    found: record.len(),
                    expected: header.len(),
                });
            }
            for ((field, name), column) in record.iter().zip(&header).zip(columns.iter_mut()) {
                let is_required = required.contains(&name.as_str());
                let value = if field.is_empty() && !is_required {
                    f64::NAN
                } else {
                    field.parse::<f64>().map_err(|_| DataError::NotANumber {
                        path: p(),
                        line,
                        column: name.clone(),
                        text: field.to_owned(),
                    })?
                };
                if is_required && !value.is_finite() {
                    return Err(DataError::NotFinite {
                        path: p(),
                        line,
                        column: name.clone(),
                        value,
                    });
                }
                column.push(value);
            }
            if let Some(t_index) = header.iter().position(|h| h == "t") {
                let t = &columns[t_index];
                if t.len() >= 2 && t[t.len() - 1] <= t[t.len() - 2] {
                    return Err(DataError::TimeNotIncreasing {
                        path: p(),
                        line,
                        previous: t[t.len() - 2],
                        value: t[t.len() - 1],
                    });
                }
            }
        }
        let len = columns.first().map_or(0, Vec::len);
        if len == 0 {
            return Err(DataError::NoRows { path: p() });
        }
        Ok(Self {
            source: p(),
            columns: header.into_iter().zip(columns).collect(),
            len,
        })
    }

    /// A dataset from columns already in memory (tests, simulations).
    pub fn from_columns(source: &str, columns: Vec<(&str, Vec<f64>)>) -> Self {
        let len = columns.first().map_or(0, |(_, c)| c.len());
        Self {
            source: PathBuf::from(source),
            columns: columns.into_iter().map(|(n, c)| (n.to_owned(), c)).collect(),
            len,
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    /// The rows from `from_s` to `to_s` (exclusive), seconds after the
    /// first row's `t`.
    pub fn window(mut self, from_s: f64, to_s: f64) -> Result<Self, DataError> {
        let t = self.column("t")?;
        let first = t.first().copied().unwrap_or(0.0);
        let rows = t.iter().map(|t| t - first).position(|s| s >= from_s).unwrap_or(t.len())
            ..t.iter().map(|t| t - first).position(|s| s >= to_s).unwrap_or(t.len());
        if rows.is_empty() {
            return Err(DataError::EmptyWindow {
                path: self.source.clone(),
                from_s,
                to_s,
                span_s: t.last().map_or(0.0, |last| last - first),
            });
        }
        for column in self.columns.values_mut() {
            *column = column[rows.clone()].to_vec();
        }
        self.len = rows.len();
        Ok(self)
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn column(&self, name: &str) -> Result<&[f64], DataError> {
        self.columns
            .get(name)
            .map(Vec::as_slice)
            .ok_or_else(|| DataError::MissingColumn {
                path: self.source.clone(),
                column: name.to_owned(),
                have: self.columns.keys().cloned().collect::<Vec<_>>().join(","),
            })
    }

    /// The mean sample time, s, from `t`.
    pub fn sample_time(&self) -> Result<f64, DataError> {
        let t = self.column("t")?;
        Ok(if t.len() < 2 {
            0.0
        } else {
            (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const REQUIRED: [&str; 5] = ["t", "u", "p_a", "p_b", "theta"];

    fn parse(text: &str) -> Result<Dataset, DataError> {
        Dataset::parse_csv(text, Path::new("run.csv"), &REQUIRED)
    }

    #[test]
    fn a_window_keeps_the_rows_of_its_seconds_and_names_an_empty_one() {
        let t: Vec<f64> = (0..10).map(|k| 5.0 + 0.5 * f64::from(k)).collect();
        let d = Dataset::from_columns("day.csv", vec![("t", t.clone()), ("theta", t)]);
        let w = d.clone().window(1.0, 2.0).expect("rows");
        assert_eq!(w.column("t").expect("t"), &[6.0, 6.5]);
        assert_eq!(w.len(), 2);
        let err = d.window(9.0, 10.0).expect_err("empty").to_string();
        assert!(err.contains("day.csv") && err.contains("4.5 s"), "{err}");
    }

    #[test]
    fn reads_columns_and_extra_ones() {
        let d = parse("t,u,p_a,p_b,theta,theta_ref\n0,0.1,80,80,0,0\n0.001,0.2,81,79,0.001,\n").expect("valid");
        assert_eq!(d.len(), 2);
        assert_eq!(d.column("u").expect("u"), &[0.1, 0.2]);
        assert!(d.column("theta_ref").expect("extra")[1].is_nan());
        assert!((d.sample_time().expect("t") - 0.001).abs() < 1e-15);
    }

    #[test]
    fn every_defect_names_file_line_and_column() {
        let cases = [
            ("", "empty"),
            ("t,u,p_a,p_b,theta\n", "no data rows"),
            ("t,u,p_a,p_b\n0,0,0,0\n", "missing column `theta`"),
            ("t,u,p_a,p_b,theta\n0,0,0,0,0\n0.001,0,0,0\n", "run.csv:3: 4 fields"),
            (
                "t,u,p_a,p_b,theta\n0,0,0,0,0\n0.001,abc,0,0,0\n",
                "run.csv:3: column `u`: `abc`",
            ),
            (
                "t,u,p_a,p_b,theta\n0,0,0,0,0\n0.001,0,NaN,0,0\n",
                "run.csv:3: column `p_a` is NaN",
            ),
            (
                "t,u,p_a,p_b,theta\n0,0,0,0,0\n0,0,0,0,0\n",
                "run.csv:3: column `t` does not increase",
            ),
        ];
        for (text, expected) in cases {
            let err = parse(text).expect_err(expected).to_string();
            assert!(err.contains(expected) && err.contains("run.csv"), "{err}");
        }
    }
}
