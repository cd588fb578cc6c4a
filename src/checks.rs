//! Configuration errors, one type for every config struct: each struct's `check` collects a
//! [`ConfigError`] per bad value (its full dotted key and why) through a [`Checker`], so that one
//! pass reports every error of a file ([`crate::Error::Config`]); where a value came from (file
//! and line, or `--set`) is added by [`Origin`].

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

/// Where the values of a pipeline came from: a file (its text, for line numbers) and the
/// `--set` overrides applied on top. Error messages say which one to fix.
#[derive(Debug, Clone, Default)]
pub struct Origin {
    pub name: String,
    pub text: Option<String>,
    pub sets: Vec<String>,
}

impl Origin {
    /// `name` with its text read from disk when it is a file.
    pub fn new(name: &str, text: Option<&str>, sets: &[String]) -> Origin {
        let text = text.map(str::to_string).or_else(|| std::fs::read_to_string(name).ok());
        Origin { name: name.to_string(), text, sets: sets.to_vec() }
    }

    /// `--set k=v` when an override gave `key` (or a table above it), else `file line N` (the
    /// line of the key under its table header), else the file.
    pub fn locate(&self, key: &str) -> String {
        if let Some(s) = self.sets.iter().rev().find(|s| {
            let k = s.split_once('=').map_or(s.as_str(), |(k, _)| k).trim();
            key == k || key.starts_with(&format!("{k}.")) || key.starts_with(&format!("{k}[")) || k.starts_with(&format!("{key}."))
        }) {
            return format!("--set {s}");
        }
        match self.text.as_deref().and_then(|t| line_of(t, key)) {
            Some(n) => format!("{} line {n}", self.name),
            None => self.name.clone(),
        }
    }
}

impl Origin {
    /// The errors, each saying where its value came from.
    pub fn errors(&self, mut errs: Vec<ConfigError>) -> crate::Error {
        for e in &mut errs {
            e.message = format!("{} ({})", e.message, self.locate(&e.key));
        }
        crate::Error::Config(errs)
    }
}

impl From<&str> for Origin {
    fn from(name: &str) -> Origin {
        Origin { name: name.into(), text: None, sets: Vec::new() }
    }
}

/// The 1-based line of a dotted key in TOML text: under the longest `[table]` header that is a
/// prefix of the key, the first `rest = ...` line (or the header itself for a table).
fn line_of(text: &str, key: &str) -> Option<usize> {
    let lines: Vec<&str> = text.lines().collect();
    let parts: Vec<&str> = key.split('.').collect();
    for cut in (0..=parts.len()).rev() {
        let (table, rest) = (parts[..cut].join("."), parts[cut..].join("."));
        let start = if cut == 0 {
            Some(0)
        } else {
            lines.iter().position(|l| l.trim().strip_prefix('[').and_then(|l| l.strip_suffix(']')).is_some_and(|h| h.trim() == table))
        };
        let Some(start) = start else { continue };
        if rest.is_empty() {
            return Some(start + 1);
        }
        for (i, l) in lines.iter().enumerate().skip(start + usize::from(cut > 0)) {
            let t = l.trim();
            if t.starts_with('[') {
                break;
            }
            if t.strip_prefix(rest.as_str()).is_some_and(|r| r.trim_start().starts_with('=')) {
                return Some(i + 1);
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_element_of_a_list_given_by_set_is_blamed_on_the_set() {
        let sets = vec!["transforms.noise.sigma=[0.0, nan]".to_string()];
        let origin = Origin::new("pipelines/generate.toml (embedded)", Some(include_str!("../pipelines/generate.toml")), &sets);
        assert_eq!(origin.locate("transforms.noise.sigma[1]"), "--set transforms.noise.sigma=[0.0, nan]");
        assert!(origin.locate("transforms.noise.seed").starts_with("pipelines/generate.toml (embedded)"));
    }

    #[test]
    fn keys_are_found_on_their_lines() {
        let t = "seed = 1\n[a]\nx = 1\n[a.b]\ny = 2\n[c]\ny = 3\n";
        assert_eq!(line_of(t, "seed"), Some(1));
        assert_eq!(line_of(t, "a.x"), Some(3));
        assert_eq!(line_of(t, "a.b.y"), Some(5));
        assert_eq!(line_of(t, "c.y"), Some(7));
        assert_eq!(line_of(t, "c"), Some(6));
        assert_eq!(line_of(t, "d.z"), None);
    }
}
