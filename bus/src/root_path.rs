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

use std::path::{Path, PathBuf};

use railmon_records::private_dir::{checked_private_dir, make_private_dir};

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
        checked_private_dir(Path::new(configured)).map_err(|why| BusError::Config {
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
        match make_private_dir(&dir) {
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
    use std::os::unix::fs::{MetadataExt, PermissionsExt};

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
