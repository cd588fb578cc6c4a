//! `blackhole`: counts what arrives and keeps nothing (benchmarks, dry runs).

use super::shards::default_dir;
use super::{BuildContext, Built, Counters, Sink, StageConfig};
use crate::checks::ConfigError;
use crate::item::Item;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// `type = "blackhole"`: counts samples and drops them.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlackholeConfig {
    pub inputs: Vec<String>,
    #[serde(default = "default_dir")]
    pub dir: String,
}

impl StageConfig for BlackholeConfig {
    super::wiring!(sink, Samples);
    fn validate(&self, _key: &str) -> Vec<ConfigError> {
        Vec::new()
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Sink(Box::new(Blackhole { counters: ctx.counters.clone(), samples: 0, pending: 0, failed: Vec::new() })))
    }
}

/// `blackhole`: counts what arrives and keeps nothing.
pub struct Blackhole {
    pub counters: Arc<Counters>,
    pub samples: usize,
    pub pending: usize,
    pub failed: Vec<(String, String)>,
}

impl Sink for Blackhole {
    fn consume(&mut self, item: Item) -> crate::Result<()> {
        match item {
            Item::Begin(..) => self.pending = 0,
            Item::Sample(s) => {
                self.pending += s.pairs.len();
                Counters::add(&self.counters.samples, s.pairs.len() as u64);
            }
            Item::End(_, Ok(())) => {
                self.samples += self.pending;
                Counters::add(&self.counters.samples_kept, self.pending as u64);
                Counters::add(&self.counters.inputs_done, 1);
            }
            Item::End(input, Err(e)) => {
                self.failed.push((input.path.clone(), e.to_string()));
                Counters::add(&self.counters.inputs_failed, 1);
            }
            _ => {}
        }
        Ok(())
    }
    fn finish(&mut self) -> crate::Result<serde_json::Value> {
        Ok(serde_json::json!({ "sink": "blackhole", "samples": self.samples }))
    }
    fn abort(&mut self) {}
    fn failures(&self) -> Vec<(String, String)> {
        self.failed.clone()
    }
}
