//! `crossline.toml`: every setting of the pipeline, with defaults.
//!
//! Parsing is a pure function of the text ([`parse`]), apart from reading the file
//! ([`load`]), so tests feed it strings. The shipped `config/crossline.toml` lists every
//! key, commented, equal to these defaults; a test keeps the two in step. Unknown keys
//! are errors, reported with the file, line and key.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::cloud::TriangulateParams;
use crate::extract::ExtractParams;
use crate::intersect::IntersectParams;
use crate::reconstruct::BackgroundParams;
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
}

/// Parses the text of a config file; `origin` only labels errors.
pub fn parse(text: &str, origin: &Path) -> Result<Config, ConfigError> {
    toml::from_str(text).map_err(|e| ConfigError::Parse {
        path: origin.to_path_buf(),
        line: e
            .span()
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
            .unwrap_or(0),
        message: e.message().trim().to_string(),
    })
}

/// Reads and parses a config file.
pub fn load(path: &Path) -> Result<Config, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
        path: path.to_path_buf(),
        source,
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
