//! Where iceoryx2 keeps its discovery files, liveness locks and event sockets. Its own default,
//! `/tmp/iceoryx2/`, sits in world-writable `/tmp` with an owner nobody checks: another user
//! could create it first and plant or read files there. railmon's default (`bus.root_path =
//! ""`) is a private directory of the user, mode 0700, owner checked, the first that works of:
//!
//! 1. `$XDG_RUNTIME_DIR/railmon/` (the user's runtime directory, itself 0700);
//! 2. `/run/railmon/` (a system service running as root, or a directory prepared for it);
//! 3. `/tmp/railmon-<uid>/` (refused if it exists and is not ours or not private).
//!
//! Each step that does not work is noted (the binaries log the notes). The service and the
//! replay find each other only with the same root path: run them as the same user in the
//! same session, or set `bus.root_path` (`RAILMON_BUS__ROOT_PATH`) for both. A root path set
//! explicitly is created 0700 if missing, and refused if it is world-writable.

use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};

use crate::BusError;

/// A root path iceoryx2 may use, and what was tried before it.
#[derive(Clone, Debug, PartialEq)]
pub struct RootPath {
    /// With a trailing `/`.
    pub path: String,
    /// Why earlier candidates were not used.
    pub notes: Vec<String>,
}

fn euid() -> u32 {
    // SAFETY: geteuid(2) has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

/// Makes sure `dir` exists, belongs to us and is private (0700); creates it 0700 if missing.
fn private_dir(dir: &Path) -> Result<(), String> {
    if !dir.exists() {
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o700)
            .create(dir)
            .map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    }
    let meta = std::fs::symlink_metadata(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    if !meta.is_dir() {
        return Err(format!("{} is not a directory", dir.display()));
    }
    if meta.uid() != euid() {
        return Err(format!(
            "{} belongs to uid {}, not to us (uid {})",
            dir.display(),
            meta.uid(),
            euid()
        ));
    }
    if meta.mode() & 0o077 != 0 {
        // Ours: make it private rather than give up.
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700))
            .map_err(|e| format!("cannot make {} private (0700): {e}", dir.display()))?;
    }
    Ok(())
}

/// An explicit `bus.root_path` held to the default's rules, and refused rather than repaired
/// where files may already have been planted in it: a directory (not a symlink to one) of this
/// user, writable by no one else, in a parent that no one else can rename it in (not writable
/// by others, or sticky like /tmp); created 0700 if missing, made private if others may read it.
fn explicit_root(dir: &Path) -> Result<(), String> {
    let dir = Path::new(dir.to_str().map_or(dir.as_os_str(), |s| {
        std::ffi::OsStr::new(s.trim_end_matches('/'))
    }));
    if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        if let Ok(meta) = std::fs::metadata(parent) {
            if meta.mode() & 0o022 != 0 && meta.mode() & 0o1000 == 0 {
                return Err(format!(
                    "its parent {} is writable by others (mode {:o}) and not sticky: anyone \
                     could replace the directory; use a private parent",
                    parent.display(),
                    meta.mode() & 0o7777
                ));
            }
        }
    }
    if let Ok(meta) = std::fs::symlink_metadata(dir) {
        if meta.file_type().is_symlink() {
            return Err("a symbolic link: give the directory itself".into());
        }
        if meta.is_dir() && meta.mode() & 0o022 != 0 {
            let who = if meta.mode() & 0o002 != 0 {
                "world-writable"
            } else {
                "group-writable"
            };
            return Err(format!(
                "{who} (mode {:o}): others could plant bus files there; use a private directory",
                meta.mode() & 0o7777
            ));
        }
    }
    private_dir(dir)
}

fn with_slash(path: &Path) -> String {
    let mut text = path.display().to_string();
    if !text.ends_with('/') {
        text.push('/');
    }
    text
}

/// The root path for `configured` (`bus.root_path`): that directory, checked, or the private
/// default when it is empty. `xdg_runtime_dir` is `$XDG_RUNTIME_DIR`.
pub fn resolve_root_path(
    configured: &str,
    xdg_runtime_dir: Option<&str>,
) -> Result<RootPath, BusError> {
    if !configured.is_empty() {
        explicit_root(Path::new(configured)).map_err(|why| BusError::Config {
            key: "bus.root_path".into(),
            reason: format!("`{configured}`: {why}"),
        })?;
        return Ok(RootPath {
            path: with_slash(Path::new(configured)),
            notes: Vec::new(),
        });
    }
    let mut candidates: Vec<PathBuf> = Vec::new();
    let mut notes = Vec::new();
    match xdg_runtime_dir {
        Some(xdg) if xdg.starts_with('/') => candidates.push(Path::new(xdg).join("railmon")),
        _ => notes.push("XDG_RUNTIME_DIR is not set".to_string()),
    }
    candidates.push(PathBuf::from("/run/railmon"));
    candidates.push(PathBuf::from(format!("/tmp/railmon-{}", euid())));
    for dir in candidates {
        match private_dir(&dir) {
            Ok(()) => {
                return Ok(RootPath {
                    path: with_slash(&dir),
                    notes,
                })
            }
            Err(why) => notes.push(why),
        }
    }
    Err(BusError::Config {
        key: "bus.root_path".into(),
        reason: format!(
            "no private directory for the bus ({}); set bus.root_path",
            notes.join("; ")
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("railmon-root-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn the_default_is_a_private_directory_under_the_runtime_dir() {
        let xdg = scratch("xdg");
        std::fs::create_dir_all(&xdg).unwrap();
        let root = resolve_root_path("", Some(xdg.to_str().unwrap())).unwrap();
        assert_eq!(root.path, format!("{}/railmon/", xdg.display()));
        let mode = std::fs::metadata(xdg.join("railmon")).unwrap().mode();
        assert_eq!(mode & 0o777, 0o700);
        std::fs::remove_dir_all(&xdg).unwrap();
    }

    #[test]
    fn an_unusable_runtime_dir_falls_back_with_a_note() {
        let missing = scratch("missing-parent").join("not/writable/\0");
        let root = resolve_root_path("", Some(missing.to_str().unwrap())).unwrap();
        assert!(!root.notes.is_empty(), "{root:?}");
        let none = resolve_root_path("", None).unwrap();
        assert!(none.notes[0].contains("XDG_RUNTIME_DIR"), "{none:?}");
        let mode = std::fs::metadata(&none.path).unwrap().mode();
        assert_eq!(mode & 0o077, 0, "{none:?}");
    }

    /// An explicit root is held to the default's rules: world- or group-writable, a symlink,
    /// or in a world-writable parent without the sticky bit: refused; a missing one is
    /// created 0700 (in a sticky parent, as under /tmp), one others may read made 0700.
    #[test]
    fn an_explicit_root_is_private_or_refused() {
        let set_mode = |p: &Path, mode| {
            std::fs::set_permissions(p, std::fs::Permissions::from_mode(mode)).unwrap()
        };
        let refused = |p: &Path| resolve_root_path(p.to_str().unwrap(), None).unwrap_err();
        let dir = scratch("explicit");
        std::fs::create_dir_all(&dir).unwrap();
        for (mode, why) in [(0o777, "world-writable"), (0o770, "group-writable")] {
            set_mode(&dir, mode);
            let err = refused(&dir);
            assert!(err.to_string().contains(why), "{err}");
        }
        set_mode(&dir, 0o777);
        let inner = dir.join("bus");
        let err = refused(&inner);
        assert!(err.to_string().contains("not sticky"), "{err}");
        assert!(!inner.exists());
        set_mode(&dir, 0o1777);
        let root = resolve_root_path(&format!("{}/", inner.display()), None).unwrap();
        assert_eq!(root.path, format!("{}/", inner.display()));
        assert_eq!(std::fs::metadata(&inner).unwrap().mode() & 0o777, 0o700);
        set_mode(&inner, 0o755);
        resolve_root_path(inner.to_str().unwrap(), None).unwrap();
        assert_eq!(std::fs::metadata(&inner).unwrap().mode() & 0o777, 0o700);
        let link = dir.join("link");
        std::os::unix::fs::symlink(&inner, &link).unwrap();
        for path in [link.display().to_string(), format!("{}/", link.display())] {
            let err = resolve_root_path(&path, None).unwrap_err();
            assert!(err.to_string().contains("symbolic link"), "{err}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
