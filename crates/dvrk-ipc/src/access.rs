//! Why a process cannot reach the sidecar's shared memory, in words.
//!
//! iceoryx2 0.10 gives every file it creates owner-only modes, applied with `fchmod` after
//! creation (so neither the umask nor a setgid directory changes them): the root path
//! (`/tmp/iceoryx2/`, 0750) and its `nodes/` and `services/` directories, the service
//! descriptions (0400), the segments in `/dev/shm` (0600) and the event sockets. A consumer
//! running as another user than the sidecar therefore fails inside iceoryx2, which reports
//! `NodeCreationFailure::InternalError` or a service error without the cause. When such a setup
//! step fails, [`find_inaccessible`] looks at the files of the domain for one this process may
//! not use, so the error can name it, its owner and what to do ([`crate::IpcError::PermissionDenied`]).
//!
//! Setup only (allocates, reads directories); never on the per-cycle path.

use std::ffi::CString;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

use iceoryx2::config::Config;

use crate::error::IpcError;

/// A file or directory of the iceoryx2 domain that this process may not use.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Inaccessible {
    pub path: PathBuf,
    /// The owner's user name (or `uid N` when it has no name).
    pub owner: String,
    /// Permission bits (e.g. 0o600).
    pub mode: u32,
}

/// The directory where POSIX shared memory lives on Linux (what `shm_open` uses).
const SHM_DIR: &str = "/dev/shm";

/// Looks for the first entry of the domain `config` that this process cannot use: the root path
/// and its node and service directories (need read, write and search), the service descriptions
/// (need read) and the domain's segments in /dev/shm (need read and write). `None` when
/// everything present is usable (the failure then has another cause).
pub fn find_inaccessible(config: &Config) -> Option<Inaccessible> {
    let root = PathBuf::from(config.global.root_path().to_string());
    let prefix = config.global.prefix.to_string();
    let rwx = libc::R_OK | libc::W_OK | libc::X_OK;
    for dir in [
        root.clone(),
        PathBuf::from(config.global.node_dir().to_string()),
        PathBuf::from(config.global.service_dir().to_string()),
    ] {
        if let Some(found) = check(&dir, rwx) {
            return Some(found);
        }
    }
    let services = PathBuf::from(config.global.service_dir().to_string());
    if let Some(found) = first_in(&services, &prefix, libc::R_OK) {
        return Some(found);
    }
    first_in(Path::new(SHM_DIR), &prefix, libc::R_OK | libc::W_OK)
}

/// The first entry of `dir` whose name starts with `prefix` that fails `access(mode)`.
fn first_in(dir: &Path, prefix: &str, mode: libc::c_int) -> Option<Inaccessible> {
    let entries = std::fs::read_dir(dir).ok()?;
    let mut names: Vec<PathBuf> = entries
        .flatten()
        .filter(|e| e.file_name().as_bytes().starts_with(prefix.as_bytes()))
        .map(|e| e.path())
        .collect();
    names.sort();
    names.iter().find_map(|p| check(p, mode))
}

/// `Some` when `path` exists and `access(path, mode)` fails with EACCES or EPERM.
fn check(path: &Path, mode: libc::c_int) -> Option<Inaccessible> {
    let meta = std::fs::metadata(path).ok()?;
    let c = CString::new(path.as_os_str().as_bytes()).ok()?;
    // SAFETY: `c` is a valid NUL-terminated path; access(2) only reads it.
    if unsafe { libc::access(c.as_ptr(), mode) } == 0 {
        return None;
    }
    let err = std::io::Error::last_os_error().raw_os_error();
    if err != Some(libc::EACCES) && err != Some(libc::EPERM) {
        return None;
    }
    Some(Inaccessible {
        path: path.to_path_buf(),
        owner: user_name(meta.uid()),
        mode: meta.mode() & 0o7777,
    })
}

/// The name of `uid` from /etc/passwd, else `uid N`.
fn user_name(uid: u32) -> String {
    std::fs::read_to_string("/etc/passwd")
        .ok()
        .and_then(|text| {
            text.lines().find_map(|l| {
                let mut f = l.split(':');
                let name = f.next()?;
                let _pw = f.next()?;
                (f.next()?.parse::<u32>().ok()? == uid).then(|| name.to_owned())
            })
        })
        .unwrap_or_else(|| format!("uid {uid}"))
}

/// Refuses a process running as root in a domain whose root path another account owns (see
/// [`IpcError::RootWouldLockOut`]). Root passes every `access(2)` check, so without this the
/// lock-out it causes would go unexplained until the service restarts.
pub fn refuse_root_in_anothers_domain(config: &Config) -> Result<(), IpcError> {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        return Ok(());
    }
    let root = PathBuf::from(config.global.root_path().to_string());
    match std::fs::metadata(&root) {
        Ok(m) if m.uid() != 0 => Err(IpcError::RootWouldLockOut {
            owner: user_name(m.uid()),
            path: root,
        }),
        _ => Ok(()),
    }
}

/// For the publishing service: refuses a domain whose root path exists and belongs to another
/// account than this process's ([`IpcError::DomainOwnedByAnother`]). A consumer may use the
/// service's domain (it must run as the same account anyway); the service itself must not
/// publish into a directory someone else created before it.
pub fn refuse_domain_of_another(config: &Config) -> Result<(), IpcError> {
    // SAFETY: geteuid has no preconditions.
    let me = unsafe { libc::geteuid() };
    let root = PathBuf::from(config.global.root_path().to_string());
    match std::fs::symlink_metadata(&root) {
        Ok(m) if m.uid() != me => Err(IpcError::DomainOwnedByAnother {
            owner: user_name(m.uid()),
            me: user_name(me),
            path: root,
        }),
        _ => Ok(()),
    }
}

/// What to do when a file of `owner` is in the way.
pub fn hint(owner: &str) -> String {
    if owner == "root" {
        // Nothing of the project runs as root on purpose: a program run with sudo left it.
        "A program using iceoryx2 was run as root (e.g. with sudo) and left it: when no \
         dvrk-sidecar and no consumer runs, remove it (sudo rm -rf /tmp/iceoryx2 /dev/shm/iox2_*), \
         and run iceoryx2 programs as the service's user; see deploy/README.md, \"Consumers\""
            .to_owned()
    } else {
        format!(
            "Run this program as {owner} (e.g. sudo -u {owner} ...): the service and its \
             consumers run under the one account chosen at install (deploy/install.sh: by \
             default the account that ran sudo, or --user NAME); see deploy/README.md, \
             \"Consumers\""
        )
    }
}

/// `err` unchanged, or [`IpcError::PermissionDenied`] when a file of the domain is the cause.
/// `during` says what failed ("creating the iceoryx2 node \"x\"").
pub(crate) fn explain(err: IpcError, config: &Config, during: String) -> IpcError {
    match find_inaccessible(config) {
        Some(Inaccessible { path, owner, mode }) => IpcError::PermissionDenied {
            during,
            hint: hint(&owner),
            path,
            owner,
            mode,
            source: Box::new(err),
        },
        None => err,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_accessible_domain_has_nothing_to_report() {
        // A domain whose root path does not exist yet: nothing there to be refused.
        let cfg =
            crate::domain_config("acc_unit_", Some("/tmp/dvrk-ipc-access-unit-none/")).unwrap();
        assert_eq!(find_inaccessible(&cfg), None);
    }

    #[test]
    fn the_hint_for_root_owned_leftovers_is_to_remove_them() {
        assert!(hint("root").contains("sudo rm -rf /tmp/iceoryx2"));
        let h = hint("dvrk-sidecar");
        assert!(
            h.contains("sudo -u dvrk-sidecar") && h.contains("--user NAME"),
            "{h}"
        );
    }

    #[test]
    fn user_names_come_from_passwd() {
        assert_eq!(user_name(0), "root");
        assert_eq!(user_name(4_000_000_000), "uid 4000000000");
    }
}
