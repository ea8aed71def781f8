//! Reading parameter files in tests. The crate itself never parses text (ARCHITECTURE.md: no
//! TOML library in the pure core); the application does, as here, then calls `from_params`.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use dvrk_compliance::{ComplianceConfig, ComplianceParams, ParamsError};

/// Why a parameter file was rejected: by the TOML parser, by the schema, or by validation.
#[derive(Debug)]
pub enum LoadError {
    Syntax(String),
    Schema(String),
    Params(ParamsError),
}

impl std::fmt::Display for LoadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LoadError::Syntax(m) => write!(f, "TOML syntax error: {m}"),
            LoadError::Schema(m) => write!(f, "schema error: {m}"),
            LoadError::Params(e) => write!(f, "{e}"),
        }
    }
}

/// Parses without validating the numbers: TOML syntax first, then the schema.
pub fn params(text: &str) -> Result<ComplianceParams, LoadError> {
    text.parse::<toml::Table>()
        .map_err(|e| LoadError::Syntax(e.to_string()))?;
    toml::from_str(text).map_err(|e| LoadError::Schema(e.to_string()))
}

/// Parses and validates.
pub fn config(text: &str) -> Result<ComplianceConfig, LoadError> {
    ComplianceConfig::from_params(params(text)?).map_err(LoadError::Params)
}
