//! Shared by the matrix and sections benches: the adhesion scenarios of `config/scenarios/`.

use std::path::{Path, PathBuf};

/// The `adhesion-*.toml` files of `config/scenarios/`, sorted, whose name contains `filter`.
pub fn scenario_paths(filter: Option<&str>) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenarios");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("config/scenarios")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            name.starts_with("adhesion-")
                && name.ends_with(".toml")
                && filter.is_none_or(|f| name.contains(f))
        })
        .collect();
    paths.sort();
    paths
}
