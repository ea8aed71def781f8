//! Who may use the sidecar's shared memory, and why a process cannot, in words.
//!
//! The project's default domain keeps its iceoryx2 state in a directory of the account's own
//! (`/tmp/dvrk-sidecar-<euid>/`, see [`crate::default_root_path`]): [`ensure_private_root`]
//! creates it 0700 and refuses it when another account could write it.
//!
//! iceoryx2 0.10 gives every file it creates owner-only modes, applied with `fchmod` after
//! creation (so neither the umask nor a setgid directory changes them): the root path
//! (0750 when iceoryx2 creates it) and its `nodes/` and `services/` directories, the service
//! descriptions (0400), the segments in `/dev/shm` (0600) and the event sockets; all but the
//! domain's global management segment, created 0666, which [`restrict_global_segment`] makes
//! 0600 once a node exists. A consumer
//! running as another user than the sidecar therefore fails inside iceoryx2, which reports
//! `NodeCreationFailure::InternalError` or a service error without the cause. When such a setup
//! step fails, [`find_inaccessible`] looks at the files of the domain for one this process may
//! not use, so the error can name it, its owner and what to do ([`crate::IpcError::PermissionDenied`]).
//!
//! Setup only (allocates, reads directories); never on the per-cycle path.

use std::ffi::CString;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::{DirBuilderExt, MetadataExt};
use std::path::{Path, PathBuf};

use iceoryx2::config::Config;

use crate::error::{IpcError, RootProblem};
use crate::services::euid;

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

/// Takes from other accounts the write access iceoryx2 0.10 leaves on the domain's global
/// management segment (`/dev/shm/<prefix><hash>_node.0_10_0.global_mgmt`, created 0666): any
/// local user could write 16 bytes into it and stop every new node of the account (issue 22).
/// Every segment of the domain whose name ends in `.global_mgmt`, is a regular file and belongs
/// to this account is set to 0600; the account's own processes are the only ones that open it
/// (another account, root included, has a domain of its own). A segment another account created
/// first is left alone: it cannot be changed from here (README.md says what then to do).
/// Setup only.
pub fn restrict_global_segment(config: &Config) {
    use std::os::unix::fs::PermissionsExt;
    let me = euid();
    for path in named(Path::new(SHM_DIR), &config.global.prefix.to_string()) {
        if !path.as_os_str().as_bytes().ends_with(b".global_mgmt") {
            continue;
        }
        // Not followed: a segment is a plain file, and /dev/shm's sticky bit keeps others from
        // putting anything else in place of ours.
        let Ok(meta) = std::fs::symlink_metadata(&path) else {
            continue;
        };
        if meta.file_type().is_file() && meta.uid() == me && meta.mode() & 0o077 != 0 {
            let _ = std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600));
        }
    }
}

/// The entries of `dir` whose name starts with `prefix`, sorted (none if it cannot be read).
fn named(dir: &Path, prefix: &str) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut names: Vec<PathBuf> = entries
        .flatten()
        .filter(|e| e.file_name().as_bytes().starts_with(prefix.as_bytes()))
        .map(|e| e.path())
        .collect();
    names.sort();
    names
}

/// The first entry of `dir` whose name starts with `prefix` that fails `access(mode)`.
fn first_in(dir: &Path, prefix: &str, mode: libc::c_int) -> Option<Inaccessible> {
    named(dir, prefix).iter().find_map(|p| check(p, mode))
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
    if euid() != 0 {
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

/// Makes the root directory of `config`'s domain private to this account, or refuses it.
///
/// Creates it with mode 0700 if missing (its parent must exist), then looks at what is there
/// without following a symbolic link (`mkdir` then `lstat`: whoever made it, what is examined
/// is what iceoryx2 will use) and refuses ([`IpcError::RootNotPrivate`], naming the path, its
/// owner, its mode and what to do) when it is a symbolic link, not a directory, another
/// account's, or writable by group or others; also when its parent lets another account
/// replace it (writable by a user other than root and this one, without the sticky bit that
/// `/tmp` has). iceoryx2 creates its own files beneath it.
///
/// [`crate::create_node`] calls it for the project's default root path, so `serve` refuses to
/// start in such a directory and every consumer gets the same error.
pub fn ensure_private_root(config: &Config) -> Result<(), IpcError> {
    ensure_private_dir(Path::new(&config.global.root_path().to_string()))
}

/// [`ensure_private_root`] for the directory `dir`.
pub fn ensure_private_dir(dir: &Path) -> Result<(), IpcError> {
    // Without its trailing '/': `lstat("link/")` would follow a symbolic link.
    let bytes = dir.as_os_str().as_bytes();
    let end = bytes.iter().rposition(|&b| b != b'/').map_or(1, |i| i + 1);
    let dir = Path::new(std::ffi::OsStr::from_bytes(&bytes[..end.min(bytes.len())]));
    let me = euid();
    let refuse = |path: &Path, problem: RootProblem, meta: &std::fs::Metadata| {
        let owner = user_name(meta.uid());
        let me_name = user_name(me);
        let shown = path.display();
        let env = crate::IPC_ROOT_ENV;
        let (what, fix) = match problem {
            RootProblem::Symlink => (
                "is a symbolic link".to_owned(),
                format!(
                    "iceoryx2 would follow it wherever it points, and whoever made it chooses \
                     where. Remove it when no program using iceoryx2 runs (sudo rm {shown}), or \
                     set {env} to a directory of this account's own"
                ),
            ),
            RootProblem::NotADirectory => (
                "is not a directory".to_owned(),
                format!(
                    "Remove it when no program using iceoryx2 runs (sudo rm {shown}), or set \
                     {env} to a directory of this account's own"
                ),
            ),
            RootProblem::OtherOwner => (
                "belongs to another account".to_owned(),
                format!(
                    "The service and its consumers keep their iceoryx2 state where only their \
                     account can write. If {owner} runs the dVRK sidecar, run this program as \
                     {owner} (sudo -u {owner} ...); otherwise {owner} created it first and \
                     could hide the service from its consumers: remove it when no program \
                     using iceoryx2 runs (sudo rm -rf {shown}), or set {env} to a directory of \
                     this account's own"
                ),
            ),
            RootProblem::WritableByOthers => (
                "is writable by group or others".to_owned(),
                format!(
                    "Another user could replace the service's discovery files and event \
                     sockets there: chmod 700 {shown}"
                ),
            ),
            RootProblem::UnsafeParent => (
                format!(
                    "is the parent of {}, and another account than root and {me_name} may \
                     write it without the sticky bit, so it could replace that directory",
                    dir.display()
                ),
                format!("Set {env} to a path in /tmp, /run or a directory of this account's own"),
            ),
        };
        let mode = meta.mode() & 0o7777;
        IpcError::RootNotPrivate {
            message: format!(
                "refusing the dVRK sidecar's shared-memory directory {shown}: it {what} (owner \
                 {owner}, mode {mode:04o}; this process runs as {me_name}). {fix}"
            ),
            path: path.to_path_buf(),
            problem,
            owner,
            mode,
        }
    };
    let io_err = |source| IpcError::RootDirectory {
        path: dir.to_path_buf(),
        source,
    };
    if let Some(parent) = dir.parent()
        && let Ok(meta) = std::fs::metadata(parent)
    {
        let others_may_write = meta.mode() & 0o022 != 0 && meta.mode() & 0o1000 == 0;
        if (meta.uid() != 0 && meta.uid() != me) || others_may_write {
            return Err(refuse(parent, RootProblem::UnsafeParent, &meta));
        }
    }
    match std::fs::DirBuilder::new().mode(0o700).create(dir) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
        Err(e) => return Err(io_err(e)),
    }
    let meta = std::fs::symlink_metadata(dir).map_err(io_err)?;
    let problem = if meta.file_type().is_symlink() {
        RootProblem::Symlink
    } else if !meta.is_dir() {
        RootProblem::NotADirectory
    } else if meta.uid() != me {
        RootProblem::OtherOwner
    } else if meta.mode() & 0o022 != 0 {
        RootProblem::WritableByOthers
    } else {
        return Ok(());
    };
    Err(refuse(dir, problem, &meta))
}

/// What to do when a file of `owner` is in the way in the domain of `config`.
pub fn hint(owner: &str, config: &Config) -> String {
    if owner == "root" {
        // Nothing of the project runs as root on purpose: a program run with sudo left it.
        format!(
            "A program using iceoryx2 was run as root (e.g. with sudo) and left it: when no \
             dvrk-sidecar and no consumer runs, remove it (sudo rm -rf {} /dev/shm/{}*), and run \
             iceoryx2 programs as the service's user; see deploy/README.md, \"Consumers\"",
            config.global.root_path(),
            config.global.prefix
        )
    } else {
        format!(
            "Run this program as {owner} (e.g. sudo -u {owner} ...): the service and its \
             consumers run under the one account chosen at install (deploy/install.sh: by \
             default the account that ran sudo, or --user NAME); see deploy/README.md, \
             \"Consumers\""
        )
    }
}

/// Where the default roots of the accounts live: `/tmp/dvrk-sidecar-<euid>/`.
const DEFAULT_ROOTS_DIR: &str = "/tmp";
const DEFAULT_ROOT_STEM: &str = "dvrk-sidecar-";

/// The default domain root of another account, found by [`other_accounts_roots`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OtherRoot {
    /// `/tmp/dvrk-sidecar-<uid>/`.
    pub path: PathBuf,
    /// The uid in its name (the account whose processes use it).
    pub uid: u32,
    /// Its owner's user name (or `uid N`).
    pub owner: String,
}

/// The default domain roots of other accounts than this process's (`/tmp/dvrk-sidecar-<uid>/`
/// with another uid), sorted by uid. A service running under another account keeps its state
/// there, out of this process's reach. Setup only (reads a directory).
pub fn other_accounts_roots() -> Vec<OtherRoot> {
    other_roots_in(Path::new(DEFAULT_ROOTS_DIR), euid())
}

fn other_roots_in(dir: &Path, me: u32) -> Vec<OtherRoot> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut found: Vec<OtherRoot> = entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name();
            let uid: u32 = name
                .to_str()?
                .strip_prefix(DEFAULT_ROOT_STEM)?
                .parse()
                .ok()?;
            let meta = std::fs::symlink_metadata(e.path()).ok()?;
            (uid != me && meta.is_dir()).then(|| OtherRoot {
                path: e.path().join(""),
                uid,
                owner: user_name(meta.uid()),
            })
        })
        .collect();
    found.sort_by_key(|r| r.uid);
    found
}

/// Why a consumer in `config`'s domain may find no publisher, when the cause may be that the
/// service runs under another account: names the other accounts' default roots that exist and
/// what to do (`None` when there are none). For the message of a consumer that waited and
/// heard nobody (`Update::Stale` before any sample), e.g. `dvrk-sidecar echo`, `watch`, the
/// Python client's `NoSample`. Setup only (reads a directory).
pub fn no_publisher_hint(config: &Config) -> Option<String> {
    no_publisher_hint_for(config, &other_accounts_roots())
}

fn no_publisher_hint_for(config: &Config, others: &[OtherRoot]) -> Option<String> {
    if others.is_empty() {
        return None;
    }
    let list = others
        .iter()
        .map(|r| format!("{} (owner {})", r.path.display(), r.owner))
        .collect::<Vec<_>>()
        .join(", ");
    let me = user_name(euid());
    let first = &others[0].owner;
    Some(format!(
        "this process ({me}) looks in {root} with the prefix {prefix}; the dVRK sidecar's \
         shared memory of other accounts exists: {list}. A service running as another account is \
         reachable only from that account: run this program as it (e.g. sudo -u {first} ...). \
         {env} cannot point at another account's directory (it must be this account's own, \
         and the prefix dvrk_<euid>_ differs as well)",
        root = config.global.root_path(),
        prefix = config.global.prefix,
        env = crate::IPC_ROOT_ENV,
    ))
}

/// `err` unchanged, or [`IpcError::PermissionDenied`] when a file of the domain is the cause.
/// `during` says what failed ("creating the iceoryx2 node \"x\"").
pub(crate) fn explain(err: IpcError, config: &Config, during: String) -> IpcError {
    match find_inaccessible(config) {
        Some(Inaccessible { path, owner, mode }) => IpcError::PermissionDenied {
            during,
            hint: hint(&owner, config),
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
        let cfg = crate::domain_config("hint_", Some("/tmp/dvrk-ipc-hint/")).unwrap();
        let h = hint("root", &cfg);
        assert!(
            h.contains("sudo rm -rf /tmp/dvrk-ipc-hint/ /dev/shm/hint_*"),
            "{h}"
        );
        let h = hint("dvrk-sidecar", &cfg);
        assert!(
            h.contains("sudo -u dvrk-sidecar") && h.contains("--user NAME"),
            "{h}"
        );
    }

    /// A fresh scratch path `/tmp/dvrk-ipc-priv-<pid>-<case>` (removed first).
    fn scratch(case: &str) -> PathBuf {
        let p = PathBuf::from(format!("/tmp/dvrk-ipc-priv-{}-{case}", std::process::id()));
        let _ = std::fs::remove_file(&p);
        let _ = std::fs::remove_dir_all(&p);
        p
    }

    fn problem(r: Result<(), IpcError>) -> (RootProblem, String) {
        match r {
            Err(e @ IpcError::RootNotPrivate { problem, .. }) => (problem, e.to_string()),
            other => panic!("expected a refusal, got {other:?}"),
        }
    }

    #[test]
    fn a_missing_root_is_created_owner_only() {
        let dir = scratch("created");
        ensure_private_dir(&dir).unwrap();
        let m = std::fs::symlink_metadata(&dir).unwrap();
        assert!(m.is_dir());
        assert_eq!(m.mode() & 0o7777, 0o700);
        assert_eq!(m.uid(), euid());
        // Again, and with the mode iceoryx2 gives a root it creates (0750): accepted as it is.
        std::fs::set_permissions(&dir, std::os::unix::fs::PermissionsExt::from_mode(0o750))
            .unwrap();
        ensure_private_dir(&dir).unwrap();
        assert_eq!(std::fs::metadata(&dir).unwrap().mode() & 0o7777, 0o750);
        std::fs::remove_dir(&dir).unwrap();
    }

    #[test]
    fn a_root_writable_by_others_is_refused_with_the_fix() {
        let dir = scratch("open");
        std::fs::create_dir(&dir).unwrap();
        std::fs::set_permissions(&dir, std::os::unix::fs::PermissionsExt::from_mode(0o777))
            .unwrap();
        let (p, msg) = problem(ensure_private_dir(&dir));
        std::fs::remove_dir(&dir).unwrap();
        assert_eq!(p, RootProblem::WritableByOthers);
        for needle in [dir.to_str().unwrap(), "mode 0777", "chmod 700"] {
            assert!(msg.contains(needle), "{needle:?} missing from: {msg}");
        }
    }

    #[test]
    fn a_symbolic_link_is_refused_not_followed() {
        let target = scratch("link-target");
        let link = scratch("link");
        std::fs::create_dir(&target).unwrap();
        std::fs::set_permissions(&target, std::os::unix::fs::PermissionsExt::from_mode(0o700))
            .unwrap();
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let (p, msg) = problem(ensure_private_dir(&link));
        // Written as a root path is (a trailing '/', which lstat would follow): still the link.
        let (slash, _) = problem(ensure_private_dir(&PathBuf::from(format!(
            "{}/",
            link.display()
        ))));
        assert_eq!(slash, RootProblem::Symlink);
        // A dangling link is refused too (mkdir does not create its target).
        std::fs::remove_dir(&target).unwrap();
        let (dangling, _) = problem(ensure_private_dir(&link));
        let target_created = target.exists();
        std::fs::remove_file(&link).unwrap();
        assert_eq!(p, RootProblem::Symlink);
        assert_eq!(dangling, RootProblem::Symlink);
        assert!(!target_created, "the link's target was created");
        assert!(
            msg.contains("is a symbolic link") && msg.contains(crate::IPC_ROOT_ENV),
            "{msg}"
        );
    }

    #[test]
    fn a_file_in_place_of_the_root_is_refused() {
        let path = scratch("file");
        std::fs::write(&path, b"").unwrap();
        let (p, _) = problem(ensure_private_dir(&path));
        std::fs::remove_file(&path).unwrap();
        assert_eq!(p, RootProblem::NotADirectory);
    }

    #[test]
    fn a_parent_others_may_write_without_sticky_bit_is_refused() {
        let parent = scratch("parent");
        std::fs::create_dir(&parent).unwrap();
        std::fs::set_permissions(&parent, std::os::unix::fs::PermissionsExt::from_mode(0o777))
            .unwrap();
        let (p, msg) = problem(ensure_private_dir(&parent.join("root")));
        let created = parent.join("root").exists();
        // With the sticky bit (as /tmp), nobody else may rename what this account creates.
        std::fs::set_permissions(
            &parent,
            std::os::unix::fs::PermissionsExt::from_mode(0o1777),
        )
        .unwrap();
        let sticky = ensure_private_dir(&parent.join("root"));
        std::fs::remove_dir_all(&parent).unwrap();
        assert_eq!(p, RootProblem::UnsafeParent);
        assert!(!created, "created a root in an unsafe parent");
        assert!(msg.contains(parent.to_str().unwrap()), "{msg}");
        assert!(sticky.is_ok(), "{sticky:?}");
    }

    #[test]
    fn a_root_another_account_owns_is_refused() {
        if euid() != 0 {
            eprintln!("skipped: needs root to give a directory to uid 65534 (chown)");
            return;
        }
        let dir = scratch("theirs");
        std::fs::create_dir(&dir).unwrap();
        std::fs::set_permissions(&dir, std::os::unix::fs::PermissionsExt::from_mode(0o700))
            .unwrap();
        std::os::unix::fs::chown(&dir, Some(65534), Some(65534)).unwrap();
        let (p, msg) = problem(ensure_private_dir(&dir));
        std::fs::remove_dir(&dir).unwrap();
        assert_eq!(p, RootProblem::OtherOwner);
        let owner = user_name(65534);
        for needle in [
            dir.to_str().unwrap(),
            &format!(
                "belongs to another account (owner {owner}, mode 0700; this process runs as root)"
            ),
            &format!("sudo -u {owner}"),
            "sudo rm -rf",
            crate::IPC_ROOT_ENV,
        ] {
            assert!(msg.contains(needle), "{needle:?} missing from: {msg}");
        }
    }

    #[test]
    fn a_root_whose_parent_is_missing_says_so() {
        let dir = scratch("noparent").join("root");
        match ensure_private_dir(&dir) {
            Err(e @ IpcError::RootDirectory { .. }) => {
                let msg = e.to_string();
                assert!(msg.contains(crate::IPC_ROOT_ENV), "{msg}");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn no_publisher_names_the_other_accounts_roots_not_ours() {
        let dir = scratch("others");
        let me = euid();
        for name in [
            format!("dvrk-sidecar-{me}"),
            "dvrk-sidecar-4242".to_owned(),
            "dvrk-sidecar-17".to_owned(),
            "dvrk-sidecar-notanumber".to_owned(),
        ] {
            std::fs::create_dir_all(dir.join(name)).unwrap();
        }
        std::fs::write(dir.join("dvrk-sidecar-99"), b"").unwrap(); // not a directory
        let found = other_roots_in(&dir, me);
        let cfg = crate::domain_config("dvrk_0_", Some("/tmp/dvrk-sidecar-0/")).unwrap();
        let hint = no_publisher_hint_for(&cfg, &found);
        std::fs::remove_dir_all(&dir).unwrap();
        let uids: Vec<u32> = found.iter().map(|r| r.uid).collect();
        assert_eq!(
            uids,
            [17, 4242]
                .into_iter()
                .filter(|u| *u != me)
                .collect::<Vec<_>>()
        );
        let hint = hint.unwrap();
        for needle in [
            &format!("{}/dvrk-sidecar-4242/", dir.display()),
            "/tmp/dvrk-sidecar-0/",
            "dvrk_0_",
            "sudo -u",
            crate::IPC_ROOT_ENV,
            "cannot point at another account's directory",
        ] {
            assert!(hint.contains(needle), "{needle:?} missing from: {hint}");
        }
        assert_eq!(no_publisher_hint_for(&cfg, &[]), None);
    }

    #[test]
    fn user_names_come_from_passwd() {
        assert_eq!(user_name(0), "root");
        assert_eq!(user_name(4_000_000_000), "uid 4000000000");
    }
}
