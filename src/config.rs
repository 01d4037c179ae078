//! Configuration errors, one type for every table: each problem is one line naming the key with
//! its table, the value and the fix. Checks push into one [`ConfigErrors`] instead of returning
//! at the first bad key, so that a file with mistakes in several tables lists them all at once.

use std::fmt;
use std::path::{Path, PathBuf};

/// One problem: `filter.max_imu_gap_s = -1.0: set a finite value greater than zero`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ConfigError {
    /// `table.key` as the file writes it (`filter.max_imu_gap_s`, `scanner[1].cluster`), a
    /// table's name for a problem of the whole table, or empty for the file itself (unreadable,
    /// not TOML).
    pub key: String,
    /// The value, when there is one to show.
    pub value: Option<String>,
    /// Line and column in the file, when the problem is at one place of its text.
    pub position: Option<(usize, usize)>,
    /// What is wrong and how to fix it.
    pub problem: String,
}

impl ConfigError {
    /// A problem with no value to show and no place in the text.
    pub(crate) fn new(key: impl Into<String>, problem: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            value: None,
            position: None,
            problem: problem.into(),
        }
    }
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut place = self.key.clone();
        if let Some(value) = &self.value {
            place += &format!(" = {value}");
        }
        if let Some((line, column)) = self.position {
            if !place.is_empty() {
                place.push(' ');
            }
            place += &format!("at line {line} column {column}");
        }
        if place.is_empty() {
            f.write_str(&self.problem)
        } else {
            write!(f, "{place}: {}", self.problem)
        }
    }
}

/// Every problem found, in the order found; Display is one line each, every line naming the
/// file when there is one.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ConfigErrors {
    file: Option<PathBuf>,
    errors: Vec<ConfigError>,
}

impl ConfigErrors {
    /// Problems of the file at `path`.
    pub(crate) fn in_file(path: &Path) -> Self {
        Self {
            file: Some(path.to_path_buf()),
            errors: Vec::new(),
        }
    }

    /// What `check` finds, or `Ok`: how a table's `validate` wraps its `check`.
    pub(crate) fn collect(check: impl FnOnce(&mut Self)) -> Result<(), Self> {
        let mut errors = Self::default();
        check(&mut errors);
        errors.into_result()
    }

    pub(crate) fn push(&mut self, error: ConfigError) {
        self.errors.push(error);
    }

    /// Checks on the keys of table `name` (`filter`, `scanner[1]`).
    pub(crate) fn table<'a>(&'a mut self, name: &'a str) -> Table<'a> {
        Table { name, errors: self }
    }

    /// `Ok` when nothing was found.
    pub(crate) fn into_result(self) -> Result<(), Self> {
        if self.errors.is_empty() {
            Ok(())
        } else {
            Err(self)
        }
    }
}

impl fmt::Display for ConfigErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, error) in self.errors.iter().enumerate() {
            if i > 0 {
                f.write_str("\n")?;
            }
            match &self.file {
                Some(path) => write!(f, "config {}: {error}", path.display())?,
                None => write!(f, "{error}")?,
            }
        }
        Ok(())
    }
}

impl std::error::Error for ConfigErrors {}

/// The keys of one table, named `table.key` in the problems.
pub(crate) struct Table<'a> {
    name: &'a str,
    errors: &'a mut ConfigErrors,
}

impl Table<'_> {
    /// Unless `ok`, records that `key` holds `value` and what to do about it. Values show as
    /// Rust prints them (`-1.0`, `inf`, `"tcp:host"`), close to how TOML writes them.
    pub(crate) fn check(
        &mut self,
        ok: bool,
        key: &str,
        value: impl fmt::Debug,
        problem: impl Into<String>,
    ) {
        if !ok {
            self.refuse(key, value, problem);
        }
    }

    /// Records that `key` holds `value` and what to do about it.
    pub(crate) fn refuse(&mut self, key: &str, value: impl fmt::Debug, problem: impl Into<String>) {
        self.errors.push(ConfigError {
            key: format!("{}.{key}", self.name),
            value: Some(format!("{value:?}")),
            position: None,
            problem: problem.into(),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_problem_is_a_line_naming_the_file_key_value_and_fix() {
        let mut errors = ConfigErrors::in_file(Path::new("/etc/ladar.toml"));
        errors
            .table("filter")
            .check(false, "max_imu_gap_s", -1.0, "set a finite value above 0");
        errors
            .table("odometry")
            .check(true, "range_sigma_m", 0.01, "unused");
        errors.push(ConfigError {
            key: "scanner[0].range_sigma".into(),
            value: Some("0.02".into()),
            position: Some((12, 1)),
            problem: "unknown key".into(),
        });
        errors.push(ConfigError::new("", "cannot read it"));
        assert_eq!(
            errors.to_string(),
            "config /etc/ladar.toml: filter.max_imu_gap_s = -1.0: set a finite value above 0\n\
             config /etc/ladar.toml: scanner[0].range_sigma = 0.02 at line 12 column 1: unknown key\n\
             config /etc/ladar.toml: cannot read it"
        );
        assert!(ConfigErrors::default().into_result().is_ok());
    }
}
