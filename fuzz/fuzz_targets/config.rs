//! The configuration file: TOML parsing and validation of arbitrary text.
#![no_main]

use std::path::Path;

use envlight::config::RawConfig;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(raw) = RawConfig::parse(text, Path::new("fuzz.toml")) {
        let _ = raw.validate();
    }
});
