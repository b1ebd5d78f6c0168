//! Directories only this user can write into: the bus root path and the data directory (events,
//! snapshots). Files planted or swapped there by another local user would be read as ours (a
//! snapshot resumed, a bus endpoint joined), so such a directory is refused rather than used,
//! and railmon's files in it are private (0600).

use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
use std::path::Path;

fn euid() -> u32 {
    // SAFETY: geteuid(2) has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

/// Makes sure `dir` exists, belongs to us and is private (0700); creates it (and its parents)
/// 0700 if missing, and makes one of ours private if others may read it.
pub fn make_private_dir(dir: &Path) -> Result<(), String> {
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
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700))
            .map_err(|e| format!("cannot make {} private (0700): {e}", dir.display()))?;
    }
    Ok(())
}

/// A directory a user named, refused rather than repaired where files may already have been
/// planted in it: a directory (not a symlink to one) of this user, writable by no one else, in
/// a parent no one else can rename it in (not writable by others, or sticky like /tmp); then
/// as [`make_private_dir`].
pub fn checked_private_dir(dir: &Path) -> Result<(), String> {
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
                "{who} (mode {:o}): others could plant files there; use a private directory",
                meta.mode() & 0o7777
            ));
        }
    }
    make_private_dir(dir)
}

/// Makes an existing file private to us (0600): SQLite and `File::create` follow the umask
/// (0644 typically), which let every local user read the events and snapshots.
pub fn make_private_file(path: &Path) -> Result<(), String> {
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))
        .map_err(|e| format!("cannot make {} private (0600): {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> std::path::PathBuf {
        let dir =
            std::env::temp_dir().join(format!("railmon-private-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn a_named_directory_open_to_others_or_a_symlink_is_refused() {
        let base = scratch("refused");
        std::fs::create_dir_all(base.join("inner")).unwrap();
        for (mode, why) in [(0o777, "world-writable"), (0o770, "group-writable")] {
            std::fs::set_permissions(base.join("inner"), std::fs::Permissions::from_mode(mode))
                .unwrap();
            let e = checked_private_dir(&base.join("inner")).unwrap_err();
            assert!(e.contains(why), "{e}");
        }
        std::fs::set_permissions(base.join("inner"), std::fs::Permissions::from_mode(0o700))
            .unwrap();
        std::os::unix::fs::symlink(base.join("inner"), base.join("link")).unwrap();
        let e = checked_private_dir(&base.join("link")).unwrap_err();
        assert!(e.contains("symbolic link"), "{e}");
        std::fs::set_permissions(&base, std::fs::Permissions::from_mode(0o777)).unwrap();
        let e = checked_private_dir(&base.join("inner")).unwrap_err();
        assert!(e.contains("not sticky"), "{e}");
        std::fs::set_permissions(&base, std::fs::Permissions::from_mode(0o700)).unwrap();
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn a_missing_directory_is_created_private_and_a_readable_one_of_ours_made_private() {
        let base = scratch("created");
        checked_private_dir(&base.join("a/b")).unwrap();
        let mode = std::fs::metadata(base.join("a/b")).unwrap().mode();
        assert_eq!(mode & 0o777, 0o700);
        std::fs::set_permissions(base.join("a/b"), std::fs::Permissions::from_mode(0o755)).unwrap();
        checked_private_dir(&base.join("a/b")).unwrap();
        let mode = std::fs::metadata(base.join("a/b")).unwrap().mode();
        assert_eq!(mode & 0o777, 0o700);
        std::fs::write(base.join("a/b/f"), b"x").unwrap();
        make_private_file(&base.join("a/b/f")).unwrap();
        let mode = std::fs::metadata(base.join("a/b/f")).unwrap().mode();
        assert_eq!(mode & 0o777, 0o600);
        std::fs::remove_dir_all(&base).unwrap();
    }
}
