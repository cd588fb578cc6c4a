//! Configuration errors, one type for every config struct: each struct's `check` collects a
//! [`ConfigError`] per bad value (its full dotted key and why) through a [`Checker`], so that one
//! pass reports every error of a file ([`crate::Error::Config`]); where a value came from (file
//! and line, or `--set`) is added by [`crate::config::Origin`].

/// A problem with a configuration value, naming its key.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigError {
    pub key: String,
    pub message: String,
}

impl std::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.key, self.message)
    }
}

/// Collects errors under a key prefix.
pub struct Checker<'a> {
    prefix: &'a str,
    pub errors: Vec<ConfigError>,
}

impl<'a> Checker<'a> {
    pub fn new(prefix: &'a str) -> Self {
        Checker { prefix, errors: Vec::new() }
    }
    pub fn fail(&mut self, key: &str, message: impl Into<String>) {
        let key = if self.prefix.is_empty() { key.to_string() } else { format!("{}.{key}", self.prefix) };
        self.errors.push(ConfigError { key, message: message.into() });
    }
    pub fn range(&mut self, key: &str, v: f64, lo: f64, hi: f64) {
        if !(v >= lo && v <= hi) {
            self.fail(key, format!("{v} is out of range (expected {lo} to {hi})"));
        }
    }
    pub fn range_usize(&mut self, key: &str, v: usize, lo: usize, hi: usize) {
        if !(lo..=hi).contains(&v) {
            self.fail(key, format!("{v} is out of range (expected {lo} to {hi})"));
        }
    }
}
