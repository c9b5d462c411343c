//! One owner per serial port: before a port is opened, an exclusive advisory lock (`flock`) is
//! taken on the device it names, symlinks resolved (so `/dev/serial/by-id/...` and the
//! `/dev/ttyUSB0` it points at are one device), and held for as long as the port is open.
//!
//! A second program on the same port (a second daemon, `scan` or `servo` during a run) is
//! refused before it writes a byte, so it cannot switch torque off or rewrite registers under
//! the program that drives the arm. `flock` stops root too, unlike the terminal's exclusive
//! mode (`TIOCEXCL`), which root ignores. The kernel holds the lock with the open file: it goes
//! when the process exits, however it exits, so a crash never leaves a stale lock.
//!
//! The refusal names the process that holds the lock, found in `/proc/locks` by the device's
//! filesystem and inode, with its command name from `/proc/PID/comm`. A holder this process
//! cannot see (another PID namespace) is refused all the same, without a name.

use std::fmt;
use std::os::fd::OwnedFd;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

use rustix::fs::{FlockOperation, Mode, OFlags};
use rustix::io::Errno;

use super::ServoError;

/// The lock on one serial device, held until dropped.
#[derive(Debug)]
pub struct PortLock {
    /// A read-only open file of the device that carries the lock: closing it releases the lock.
    _file: OwnedFd,
    device: PathBuf,
}

/// The process that holds a port's lock.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    /// Its process id.
    pub pid: u32,
    /// Its command name (`/proc/PID/comm`), when readable.
    pub command: Option<String>,
}

impl fmt::Display for Holder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.command {
            Some(command) => write!(f, "process {} ({command})", self.pid),
            None => write!(f, "process {}", self.pid),
        }
    }
}

impl PortLock {
    /// Lock the device `port` names (symlinks resolved), without waiting: refused with
    /// [`ServoError::InUse`] when another open file holds it (another process, or another
    /// opening in this one), with [`ServoError::Open`] when the device cannot be opened.
    /// Nothing is written to the device.
    pub fn acquire(port: &Path) -> Result<Self, ServoError> {
        let open_error = |source: std::io::Error| ServoError::Open {
            port: port.to_path_buf(),
            source,
        };
        let device = std::fs::canonicalize(port).map_err(open_error)?;
        // Read-only; not as a controlling terminal; without waiting for a modem's carrier.
        let flags = OFlags::RDONLY | OFlags::NOCTTY | OFlags::NONBLOCK | OFlags::CLOEXEC;
        let file = match rustix::fs::open(&device, flags, Mode::empty()) {
            Ok(file) => file,
            // The terminal is in exclusive mode (`TIOCEXCL`), set by the program that has it.
            Err(Errno::BUSY) => {
                let holder = std::fs::metadata(&device)
                    .ok()
                    .and_then(|m| holder_of(m.dev(), m.ino()));
                return Err(in_use(port, device, holder));
            }
            Err(e) => return Err(open_error(e.into())),
        };
        match rustix::fs::flock(&file, FlockOperation::NonBlockingLockExclusive) {
            Ok(()) => Ok(Self {
                _file: file,
                device,
            }),
            Err(Errno::WOULDBLOCK) => {
                let holder = rustix::fs::fstat(&file)
                    .ok()
                    .and_then(|st| holder_of(st.st_dev, st.st_ino));
                Err(in_use(port, device, holder))
            }
            Err(e) => {
                let e = std::io::Error::from(e);
                Err(open_error(std::io::Error::new(
                    e.kind(),
                    format!("locking {}: {e}", device.display()),
                )))
            }
        }
    }

    /// The device locked: the port's path with symlinks resolved.
    pub fn device(&self) -> &Path {
        &self.device
    }
}

fn in_use(port: &Path, device: PathBuf, holder: Option<Holder>) -> ServoError {
    ServoError::InUse {
        port: port.to_path_buf(),
        device,
        holder,
    }
}

/// The process holding a `flock` on the file of filesystem `dev` and inode `inode`, if
/// `/proc/locks` shows one this process can see.
fn holder_of(dev: u64, inode: u64) -> Option<Holder> {
    let locks = std::fs::read_to_string("/proc/locks").ok()?;
    let pid = flock_holder(
        &locks,
        rustix::fs::major(dev),
        rustix::fs::minor(dev),
        inode,
    )?;
    let command = std::fs::read_to_string(format!("/proc/{pid}/comm"))
        .ok()
        .map(|c| c.trim().to_owned())
        .filter(|c| !c.is_empty());
    Some(Holder { pid, command })
}

/// The pid that holds a `flock` on the file `(major, minor, inode)`, from the text of
/// `/proc/locks`.
///
/// A line reads `1: FLOCK  ADVISORY  WRITE 4711 00:1a:3 0 EOF`: the filesystem's major and
/// minor numbers in hex, the inode in decimal. A waiter's line has `->` after the number and
/// is skipped, as are other kinds of lock (POSIX, OFD, leases: they do not conflict with
/// `flock`) and a pid of 0 or below (a holder outside this PID namespace).
pub fn flock_holder(locks: &str, major: u32, minor: u32, inode: u64) -> Option<u32> {
    locks.lines().find_map(|line| {
        let mut fields = line.split_whitespace().skip(1);
        if fields.next()? != "FLOCK" {
            return None;
        }
        let pid: i64 = fields.nth(2)?.parse().ok()?;
        let mut file = fields.next()?.split(':');
        let file_major = u32::from_str_radix(file.next()?, 16).ok()?;
        let file_minor = u32::from_str_radix(file.next()?, 16).ok()?;
        let file_inode: u64 = file.next()?.parse().ok()?;
        if (file_major, file_minor, file_inode) != (major, minor, inode) {
            return None;
        }
        u32::try_from(pid).ok().filter(|&pid| pid > 0)
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    /// `/proc/locks` with a daemon on `/dev/pts/3` (devpts is 0:26, hex 1a), a waiter for it,
    /// and other locks around it.
    const LOCKS: &str = "\
1: POSIX  ADVISORY  WRITE 880 00:1a:3 0 EOF
2: FLOCK  ADVISORY  WRITE 912 00:1a:4 0 EOF
3: OFDLCK ADVISORY  READ  -1 08:02:1835023 0 EOF
4: FLOCK  ADVISORY  WRITE 4711 00:1a:3 0 EOF
4: -> FLOCK  ADVISORY  WRITE 5000 00:1a:3 0 EOF
5: FLOCK  ADVISORY  WRITE 77 103:05:3 0 EOF
6: LEASE  ACTIVE    READ  900 00:1a:3 0 EOF
";

    #[test]
    fn the_flock_on_the_device_names_its_holder() {
        assert_eq!(flock_holder(LOCKS, 0, 26, 3), Some(4711));
        assert_eq!(flock_holder(LOCKS, 0, 26, 4), Some(912));
    }

    #[test]
    fn major_and_minor_are_read_in_hex_the_inode_in_decimal() {
        // 103:05 is major 0x103 = 259, minor 5.
        assert_eq!(flock_holder(LOCKS, 259, 5, 3), Some(77));
        assert_eq!(flock_holder(LOCKS, 103, 5, 3), None);
        assert_eq!(flock_holder(LOCKS, 0, 0x1a, 0x3), Some(4711));
    }

    #[test]
    fn other_kinds_of_lock_waiters_and_other_files_name_nobody() {
        // Only a POSIX lock on inode 3 of 0:27; an OFD lock has no pid.
        let posix_only = "1: POSIX  ADVISORY  WRITE 880 00:1b:3 0 EOF\n";
        assert_eq!(flock_holder(posix_only, 0, 27, 3), None);
        assert_eq!(flock_holder(LOCKS, 8, 2, 1835023), None);
        let waiter_only = "4: -> FLOCK  ADVISORY  WRITE 5000 00:1a:9 0 EOF\n";
        assert_eq!(flock_holder(waiter_only, 0, 26, 9), None);
        assert_eq!(flock_holder(LOCKS, 0, 26, 99), None);
        assert_eq!(flock_holder("", 0, 26, 3), None);
    }

    #[test]
    fn a_holder_out_of_sight_or_a_damaged_line_names_nobody() {
        let hidden = "1: FLOCK  ADVISORY  WRITE 0 00:1a:3 0 EOF\n";
        assert_eq!(flock_holder(hidden, 0, 26, 3), None);
        let damaged = "1: FLOCK  ADVISORY  WRITE 12 00:zz:3 0 EOF\n1: FLOCK\n";
        assert_eq!(flock_holder(damaged, 0, 26, 3), None);
    }

    #[test]
    fn a_second_lock_on_a_device_is_refused_naming_this_process_and_released_on_drop() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("ttyFAKE");
        std::fs::write(&file, b"").unwrap();
        let link = dir.path().join("by-id");
        std::os::unix::fs::symlink(&file, &link).unwrap();
        let first = PortLock::acquire(&file).unwrap();
        assert_eq!(first.device(), std::fs::canonicalize(&file).unwrap());
        // Another name for the same file collides.
        match PortLock::acquire(&link) {
            Err(ServoError::InUse {
                port,
                device,
                holder,
            }) => {
                assert_eq!(port, link);
                assert_eq!(device, first.device());
                let holder = holder.unwrap();
                assert_eq!(holder.pid, std::process::id());
            }
            other => panic!("a second lock: {other:?}"),
        }
        drop(first);
        assert!(PortLock::acquire(&link).is_ok());
    }

    #[test]
    fn a_missing_port_is_an_open_error_naming_it() {
        let e = PortLock::acquire(Path::new("/dev/does-not-exist")).unwrap_err();
        assert!(
            matches!(&e, ServoError::Open { port, .. } if port == Path::new("/dev/does-not-exist")),
            "{e:?}"
        );
    }
}
