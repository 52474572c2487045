//! `crossline.toml`: every setting of the pipeline, with defaults.
//!
//! Parsing is a pure function of the text ([`parse`]), apart from reading the file
//! ([`load`]), so tests feed it strings. The shipped `config/crossline.toml` lists every
//! key, commented, equal to these defaults; a test keeps the two in step. Unknown keys
//! are errors, reported with the file, line and key; so are numbers out of the range
//! [`bounds`] gives each key, and files larger than [`MAX_FILE_BYTES`].

pub mod bounds;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::cloud::TriangulateParams;
use crate::extract::rolling::BackgroundParams;
use crate::extract::ExtractParams;
use crate::intersect::IntersectParams;
use crate::serve::ServeConfig;
use crate::solve::SolveParams;

/// The whole configuration file.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub background: BackgroundParams,
    pub extract: ExtractParams,
    pub intersect: IntersectParams,
    pub solve: SolveParams,
    pub triangulate: TriangulateParams,
    pub serve: ServeConfig,
}

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}:{line}: {key} = {value}: expected {expected}")]
    Range {
        path: PathBuf,
        line: usize,
        key: String,
        value: String,
        expected: String,
    },
    #[error("{path}: {bytes} bytes is not a config file (at most {MAX_FILE_BYTES})")]
    TooLarge { path: PathBuf, bytes: u64 },
}

/// Largest config file read: the shipped one, with every key commented, is 10 KB.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// Reads a whole small text file, refusing one larger than `max` bytes before reading
/// it (a file given by mistake, a device, a FIFO that never ends), so that parsing
/// never sees more than `max` bytes. `Err(Ok(len))` when it is too large.
pub fn read_capped(path: &Path, max: u64) -> Result<String, Result<u64, std::io::Error>> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(Err)?;
    let mut text = String::new();
    let got = file.take(max + 1).read_to_string(&mut text).map_err(Err)? as u64;
    if got > max {
        let len = std::fs::metadata(path).map_or(got, |m| m.len().max(got));
        return Err(Ok(len));
    }
    Ok(text)
}

/// Line (1-based) of `key = ` in `[section]` of `text`, or 0 when not found.
fn line_of(text: &str, dotted: &str) -> usize {
    let (section, key) = dotted.split_once('.').unwrap_or(("", dotted));
    let key = key.rsplit('.').next().unwrap_or(key);
    let mut in_section = section.is_empty();
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.starts_with('[') {
            let name = t.trim_matches(|c| c == '[' || c == ']').trim();
            in_section = name == section || name.starts_with(&format!("{section}."));
        } else if in_section
            && t.strip_prefix(key)
                .is_some_and(|rest| rest.trim_start().starts_with('='))
        {
            return i + 1;
        }
    }
    0
}

/// Parses the text of a config file; `origin` only labels errors.
pub fn parse(text: &str, origin: &Path) -> Result<Config, ConfigError> {
    let syntax = |e: toml::de::Error| ConfigError::Parse {
        path: origin.to_path_buf(),
        line: e
            .span()
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
            .unwrap_or(0),
        message: crate::truncate_echo(e.message().trim()),
    };
    let config: Config = toml::from_str(text).map_err(syntax)?;
    let raw: toml::Value = toml::from_str(text).map_err(syntax)?;
    if let Some((key, value, expected)) = bounds::check(&raw) {
        return Err(ConfigError::Range {
            path: origin.to_path_buf(),
            line: line_of(text, &key),
            key: format!("[{}] {}", key.split('.').next().unwrap_or(""), {
                key.split_once('.').map_or(key.as_str(), |(_, k)| k)
            }),
            value: crate::truncate_echo(&value),
            expected,
        });
    }
    Ok(config)
}

/// Reads and parses a config file.
pub fn load(path: &Path) -> Result<Config, ConfigError> {
    let text = read_capped(path, MAX_FILE_BYTES).map_err(|e| match e {
        Ok(bytes) => ConfigError::TooLarge {
            path: path.to_path_buf(),
            bytes,
        },
        Err(source) => ConfigError::Io {
            path: path.to_path_buf(),
            source,
        },
    })?;
    parse(&text, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_config_equals_the_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/crossline.toml");
        let text = std::fs::read_to_string(&path).expect("config/crossline.toml");
        let shipped = parse(&text, &path).expect("parses");
        let default = Config::default();
        assert_eq!(
            serde_json::to_value(&shipped).expect("json"),
            serde_json::to_value(&default).expect("json"),
            "config/crossline.toml drifted from Config::default()"
        );
        // Every default key is written out in the shipped file (not left implicit).
        let table: toml::Table = toml::from_str(&text).expect("toml");
        let json = serde_json::to_value(&default).expect("json");
        for (section, keys) in json.as_object().expect("object") {
            let written = table.get(section).and_then(|t| t.as_table());
            let keys = keys.as_object().into_iter().flatten();
            // Optional keys (null by default) are shown commented out instead.
            for (key, _) in keys.filter(|(_, value)| !value.is_null()) {
                assert!(
                    written.is_some_and(|t| t.contains_key(key)),
                    "config/crossline.toml lacks [{section}] {key}"
                );
            }
        }
    }

    #[test]
    fn every_number_of_the_config_has_bounds() {
        fn numbers(v: &serde_json::Value, key: &str, out: &mut Vec<String>) {
            match v {
                serde_json::Value::Object(m) => {
                    for (k, v) in m {
                        let key = if key.is_empty() {
                            k.clone()
                        } else {
                            format!("{key}.{k}")
                        };
                        numbers(v, &key, out);
                    }
                }
                serde_json::Value::Array(a) => a.iter().for_each(|v| numbers(v, key, out)),
                serde_json::Value::Number(_) => out.push(key.to_string()),
                _ => {}
            }
        }
        let mut keys = Vec::new();
        numbers(
            &serde_json::to_value(Config::default()).expect("json"),
            "",
            &mut keys,
        );
        assert!(keys.len() > 40, "{keys:?}");
        for key in keys {
            assert!(
                bounds::BOUNDS.iter().any(|(k, _, _)| *k == key),
                "{key} has no entry in config::bounds::BOUNDS"
            );
        }
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/crossline.toml");
        load(&shipped).expect("the shipped config is within its bounds");
    }

    #[test]
    fn absurd_counts_and_durations_are_refused_naming_key_and_value() {
        for (text, key, value) in [
            (
                "[serve]\ncheckpoint_interval_s = inf\n",
                "[serve] checkpoint_interval_s",
                "inf",
            ),
            (
                "[serve]\ndrain_timeout_s = 1e300\n",
                "[serve] drain_timeout_s",
                "1e300",
            ),
            (
                "[serve]\ndrain_timeout_s = -1.0\n",
                "[serve] drain_timeout_s",
                "-1",
            ),
            (
                "[serve]\ncheckpoint_interval_s = nan\n",
                "[serve] checkpoint_interval_s",
                "nan",
            ),
            (
                "[solve]\nrefine_rounds = 1000000000\n",
                "[solve] refine_rounds",
                "1000000000",
            ),
            ("[serve]\nworkers = 1000000\n", "[serve] workers", "1000000"),
            (
                "[serve]\nring_slots = 100000000\n",
                "[serve] ring_slots",
                "100000000",
            ),
            (
                "[serve]\nclient_queue_mib = 17592186044416\n",
                "[serve] client_queue_mib",
                "17592186044416",
            ),
            (
                "[background]\nmedian_frames = 1000000000\n",
                "[background] median_frames",
                "1000000000",
            ),
        ] {
            let err = parse(&format!("# a comment\n{text}"), Path::new("my.toml")).expect_err(text);
            let msg = err.to_string();
            assert!(msg.starts_with("my.toml:3: "), "{msg}");
            assert!(msg.contains(key), "{msg}");
            assert!(msg.contains(value), "{msg}");
            assert!(msg.contains("expected"), "{msg}");
        }
        let text =
            "[[extract.lasers]]\nname = \"red\"\nhue_deg = [300.0, 1e9]\ndisplay_rgb = [1, 2, 3]\n";
        let err = parse(text, Path::new("my.toml")).expect_err("hue");
        assert!(err.to_string().contains("hue_deg = 1000000000"), "{err}");
    }

    #[test]
    fn a_huge_config_file_is_refused_before_parsing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("big.toml");
        let mut text = String::from("[solve]\n");
        while (text.len() as u64) <= MAX_FILE_BYTES {
            text.push_str("# padding padding padding padding padding padding padding\n");
        }
        std::fs::write(&path, &text).expect("write");
        let err = load(&path).expect_err("too large");
        assert!(matches!(err, ConfigError::TooLarge { .. }), "{err}");
        assert!(err.to_string().contains("big.toml"), "{err}");
    }

    #[test]
    fn errors_name_file_line_and_key() {
        let err = parse("[solve]\n\nno_such_key = 3\n", Path::new("my.toml")).expect_err("unknown");
        let msg = err.to_string();
        assert!(msg.starts_with("my.toml:3:"), "{msg}");
        assert!(msg.contains("no_such_key"), "{msg}");
        let err = parse(
            "[background]\nmedian_frames = \"many\"\n",
            Path::new("my.toml"),
        )
        .expect_err("type");
        assert!(err.to_string().starts_with("my.toml:2:"), "{err}");
    }
}
