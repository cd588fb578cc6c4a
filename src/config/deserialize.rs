//! serde over a whole table, every error at once: each error's culprit key found and removed,
//! then the rest tried again. Where an error is, is the typed path serde walked to it
//! (`serde_path_to_error`), not text read back from the toml crate's message.

use crate::checks::ConfigError;

/// Deserialises `table` as `T`, collecting every type error and unknown key (serde stops at the
/// first): each error's culprit is the leaf whose removal makes that error go away; it is
/// removed and the rest tried again. Returns the value (with the bad keys at their defaults) if
/// one could be made, and the errors with their full keys.
pub fn deserialize_all<T: serde::de::DeserializeOwned>(table: &toml::Table) -> (Option<T>, Vec<ConfigError>) {
    fn leaves(t: &toml::Table, prefix: &str, out: &mut Vec<String>) {
        for (k, v) in t {
            let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
            match v {
                toml::Value::Table(sub) if !sub.is_empty() => leaves(sub, &key, out),
                _ => out.push(key),
            }
        }
    }
    fn remove(t: &mut toml::Table, key: &str) {
        match key.split_once('.') {
            Some((head, rest)) => {
                if let Some(toml::Value::Table(sub)) = t.get_mut(head) {
                    remove(sub, rest);
                }
            }
            None => {
                t.remove(key);
            }
        }
    }
    fn get<'a>(t: &'a toml::Table, key: &str) -> Option<&'a toml::Table> {
        key.split('.').filter(|k| !k.is_empty()).try_fold(t, |t, k| t.get(k)?.as_table())
    }
    // An error: its message, the table key serde was in (map keys up to the first array index
    // or enum), and both as one string to tell two errors apart.
    let de = |t: &toml::Table| {
        serde_path_to_error::deserialize::<_, T>(toml::Value::Table(t.clone())).map_err(|e| {
            let at: Vec<String> = e
                .path()
                .iter()
                .map_while(|s| match s {
                    serde_path_to_error::Segment::Map { key } => Some(key.clone()),
                    _ => None,
                })
                .collect();
            let message = e.inner().message().trim().to_string();
            (message.clone(), at.join("."), format!("{message} at {}", e.path()))
        })
    };
    let mut t = table.clone();
    let mut errs = Vec::new();
    for _ in 0..256 {
        let (message, at, e) = match de(&t) {
            Ok(v) => return (Some(v), errs),
            Err(e) => e,
        };
        let mut cands = Vec::new();
        if let Some(sub) = get(&t, &at) {
            leaves(sub, &at, &mut cands);
        } else if !at.is_empty() {
            // The error names a value itself (`seed = -4`): that value is the culprit.
            cands.push(at.clone());
        }
        let culprit = cands.into_iter().find(|leaf| {
            let mut u = t.clone();
            remove(&mut u, leaf);
            match de(&u) {
                Ok(_) => true,
                Err((m2, _, e2)) => e2 != e && !m2.contains("missing field"),
            }
        });
        match culprit {
            Some(leaf) => {
                errs.push(ConfigError { key: leaf.clone(), message });
                remove(&mut t, &leaf);
            }
            None => {
                errs.push(ConfigError { key: if at.is_empty() { "(file)".into() } else { at }, message });
                return (None, errs);
            }
        }
    }
    (None, errs)
}
