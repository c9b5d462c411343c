//! What Linux sysfs says about serial ports: the FTDI latency timer of a `/dev/ttyUSB*` port
//! (`bus/usb-serial/devices/ttyUSBn/latency_timer`, in ms) and the list of serial ports with
//! their USB vendor and product ids (`class/tty/*/device`). The sysfs root is a parameter, so
//! tests run on a fake tree.
//!
//! The FTDI driver's default latency timer is 16 ms: a reply then waits up to 16 ms in the
//! adapter before the computer sees it, which caps a 12-servo loop near 20 Hz. 1 ms is what a
//! fast loop needs.

use std::fs;
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::wire::Adapter;

/// A sysfs tree (normally `/sys`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sysfs {
    root: PathBuf,
}

impl Default for Sysfs {
    fn default() -> Self {
        Self::system()
    }
}

/// What [`Sysfs::ensure_low_latency`] found and did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Latency {
    /// Not a `ttyUSB` port, or its driver has no latency timer (not FTDI): nothing to do.
    NotApplicable,
    /// Already at 1 ms.
    Low,
    /// Was `from_ms`, now 1 ms.
    Lowered {
        /// The value before.
        from_ms: u32,
    },
    /// Is `ms` and could not be written: run `command` (as root) to fix it.
    TooHigh {
        /// The current value.
        ms: u32,
        /// The shell command that sets it to 1.
        command: String,
        /// Why the write failed.
        error: String,
    },
    /// The file exists but could not be read or parsed.
    Unreadable {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        error: String,
    },
}

impl Latency {
    /// The adapter the port is behind, for the wire bound: an FTDI chip holding a reply's last
    /// partial USB packet for its latency timer (1 ms once lowered). `None` where no latency
    /// timer was found.
    pub fn adapter(&self) -> Option<Adapter> {
        match self {
            Self::Low | Self::Lowered { .. } => Some(Adapter::FTDI_1MS),
            Self::TooHigh { ms, .. } => Some(Adapter::ftdi(Duration::from_millis(u64::from(*ms)))),
            Self::NotApplicable | Self::Unreadable { .. } => None,
        }
    }
}

/// USB identity of a serial port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UsbInfo {
    /// Vendor id.
    pub vid: u16,
    /// Product id.
    pub pid: u16,
    /// Manufacturer string, if any.
    pub manufacturer: Option<String>,
    /// Product string, if any.
    pub product: Option<String>,
    /// Serial number, if any.
    pub serial: Option<String>,
}

impl UsbInfo {
    /// The adapter this vendor:product usually is, for the ones Dynamixel users meet.
    pub fn known_adapter(&self) -> Option<&'static str> {
        match (self.vid, self.pid) {
            (0x0403, 0x6014) => Some("ROBOTIS U2D2 (FTDI FT232H)"),
            (0x0403, 0x6001) => Some("FTDI FT232R (e.g. ROBOTIS USB2Dynamixel)"),
            (0x0403, _) => Some("FTDI adapter"),
            (0x2f5d, _) => Some("ROBOTIS board"),
            _ => None,
        }
    }
}

/// One serial port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PortInfo {
    /// Device file, `/dev/<name>`.
    pub path: PathBuf,
    /// Kernel name (`ttyUSB0`).
    pub name: String,
    /// USB identity, for a USB adapter.
    pub usb: Option<UsbInfo>,
}

fn read_trimmed(path: &Path) -> Option<String> {
    fs::read_to_string(path)
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
}

fn read_hex(path: &Path) -> Option<u16> {
    u16::from_str_radix(&read_trimmed(path)?, 16).ok()
}

/// The shell command that sets the latency timer at `path` to 1 ms.
pub fn latency_command(path: &Path) -> String {
    format!("echo 1 | sudo tee {}", path.display())
}

impl Sysfs {
    /// The real sysfs at `/sys`.
    pub fn system() -> Self {
        Self::new("/sys")
    }

    /// A sysfs tree at `root` (a fake one in tests).
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    /// The latency timer file of `port` (following symlinks such as `/dev/serial/by-id/...`),
    /// if it is a `ttyUSB` port.
    pub fn latency_timer_path(&self, port: &Path) -> Option<PathBuf> {
        let real = port.canonicalize().unwrap_or_else(|_| port.to_path_buf());
        let name = real.file_name()?.to_str()?;
        name.starts_with("ttyUSB").then(|| {
            self.root
                .join("bus/usb-serial/devices")
                .join(name)
                .join("latency_timer")
        })
    }

    /// The latency timer of `port`, ms (`None`: not an FTDI `ttyUSB` port, or unreadable).
    pub fn latency_ms(&self, port: &Path) -> Option<u32> {
        read_trimmed(&self.latency_timer_path(port)?)?.parse().ok()
    }

    /// Set the latency timer of `port` to 1 ms if it is higher and the file is writable.
    pub fn ensure_low_latency(&self, port: &Path) -> Latency {
        let Some(path) = self.latency_timer_path(port) else {
            return Latency::NotApplicable;
        };
        if !path.exists() {
            return Latency::NotApplicable;
        }
        let ms = match fs::read_to_string(&path).map(|s| s.trim().parse::<u32>()) {
            Ok(Ok(ms)) => ms,
            Ok(Err(e)) => {
                return Latency::Unreadable {
                    path,
                    error: e.to_string(),
                }
            }
            Err(e) => {
                return Latency::Unreadable {
                    path,
                    error: e.to_string(),
                }
            }
        };
        if ms <= 1 {
            return Latency::Low;
        }
        match fs::write(&path, "1") {
            Ok(()) => Latency::Lowered { from_ms: ms },
            Err(e) => Latency::TooHigh {
                ms,
                command: latency_command(&path),
                error: e.to_string(),
            },
        }
    }

    /// Serial ports with a device behind them (USB adapters with their ids, and on-board
    /// UARTs other than the legacy `ttyS*`), sorted by name.
    pub fn ports(&self) -> std::io::Result<Vec<PortInfo>> {
        let mut out = Vec::new();
        for entry in fs::read_dir(self.root.join("class/tty"))? {
            let entry = entry?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let device = entry.path().join("device");
            if !device.exists() {
                continue;
            }
            let real = device.canonicalize().unwrap_or(device);
            let usb = real.ancestors().take(4).find_map(|dir| {
                Some(UsbInfo {
                    vid: read_hex(&dir.join("idVendor"))?,
                    pid: read_hex(&dir.join("idProduct"))?,
                    manufacturer: read_trimmed(&dir.join("manufacturer")),
                    product: read_trimmed(&dir.join("product")),
                    serial: read_trimmed(&dir.join("serial")),
                })
            });
            if usb.is_none() && name.starts_with("ttyS") {
                continue;
            }
            out.push(PortInfo {
                path: Path::new("/dev").join(&name),
                name,
                usb,
            });
        }
        out.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(out)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn fake_ftdi(root: &Path, name: &str, value: &str) -> PathBuf {
        let dir = root.join("bus/usb-serial/devices").join(name);
        fs::create_dir_all(&dir).unwrap();
        let file = dir.join("latency_timer");
        fs::write(&file, value).unwrap();
        file
    }

    #[test]
    fn the_latency_timer_is_lowered_to_one_ms() {
        let root = tempfile::tempdir().unwrap();
        let file = fake_ftdi(root.path(), "ttyUSB3", "16\n");
        let sysfs = Sysfs::new(root.path());
        let port = Path::new("/dev/ttyUSB3");
        assert_eq!(sysfs.latency_ms(port), Some(16));
        assert_eq!(
            sysfs.ensure_low_latency(port),
            Latency::Lowered { from_ms: 16 }
        );
        assert_eq!(fs::read_to_string(&file).unwrap(), "1");
        assert_eq!(sysfs.ensure_low_latency(port), Latency::Low);
    }

    #[test]
    fn the_wire_bound_counts_the_latency_timer_the_port_is_left_with() {
        assert_eq!(Latency::Low.adapter(), Some(Adapter::FTDI_1MS));
        assert_eq!(
            Latency::Lowered { from_ms: 16 }.adapter(),
            Some(Adapter::FTDI_1MS)
        );
        let stuck = Latency::TooHigh {
            ms: 16,
            command: String::new(),
            error: String::new(),
        };
        assert_eq!(
            stuck.adapter().map(|a| a.latency),
            Some(Duration::from_millis(16))
        );
        assert_eq!(Latency::NotApplicable.adapter(), None);
    }

    #[test]
    fn other_ports_are_left_alone() {
        let root = tempfile::tempdir().unwrap();
        let sysfs = Sysfs::new(root.path());
        for port in ["/dev/pts/4", "/dev/ttyACM0", "/dev/ttyUSB9"] {
            assert_eq!(
                sysfs.ensure_low_latency(Path::new(port)),
                Latency::NotApplicable
            );
        }
        fake_ftdi(root.path(), "ttyUSB1", "fast");
        assert!(matches!(
            sysfs.ensure_low_latency(Path::new("/dev/ttyUSB1")),
            Latency::Unreadable { .. }
        ));
    }

    #[test]
    fn a_read_only_timer_gives_the_exact_command() {
        use std::os::unix::fs::PermissionsExt;
        let root = tempfile::tempdir().unwrap();
        let file = fake_ftdi(root.path(), "ttyUSB0", "16");
        fs::set_permissions(&file, fs::Permissions::from_mode(0o444)).unwrap();
        let expected = format!("echo 1 | sudo tee {}", file.display());
        assert_eq!(latency_command(&file), expected);
        // Root may write a read-only file: then the timer is simply lowered.
        match Sysfs::new(root.path()).ensure_low_latency(Path::new("/dev/ttyUSB0")) {
            Latency::TooHigh { ms, command, .. } => assert_eq!((ms, command), (16, expected)),
            Latency::Lowered { from_ms } => assert_eq!(from_ms, 16),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn ports_list_usb_ids_and_name_a_u2d2() {
        let root = tempfile::tempdir().unwrap();
        let r = root.path();
        // ttyUSB0: an FTDI FT232H behind usb-serial, as sysfs lays it out.
        let usb_dev = r.join("devices/pci0000:00/usb1/1-1");
        let iface = usb_dev.join("1-1:1.0");
        fs::create_dir_all(iface.join("ttyUSB0")).unwrap();
        fs::write(usb_dev.join("idVendor"), "0403\n").unwrap();
        fs::write(usb_dev.join("idProduct"), "6014\n").unwrap();
        fs::write(usb_dev.join("product"), "USB <-> Serial Converter\n").unwrap();
        fs::create_dir_all(r.join("class/tty/ttyUSB0")).unwrap();
        std::os::unix::fs::symlink(iface.join("ttyUSB0"), r.join("class/tty/ttyUSB0/device"))
            .unwrap();
        // ttyS0: a legacy UART, skipped; tty0: no device, skipped; ttyAMA0: listed without USB.
        for (name, dev) in [("ttyS0", true), ("tty0", false), ("ttyAMA0", true)] {
            let d = r.join("class/tty").join(name);
            fs::create_dir_all(&d).unwrap();
            if dev {
                fs::create_dir_all(d.join("device")).unwrap();
            }
        }
        let ports = Sysfs::new(r).ports().unwrap();
        let names: Vec<&str> = ports.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["ttyAMA0", "ttyUSB0"]);
        let usb = ports[1].usb.as_ref().unwrap();
        assert_eq!((usb.vid, usb.pid), (0x0403, 0x6014));
        assert_eq!(usb.known_adapter(), Some("ROBOTIS U2D2 (FTDI FT232H)"));
        assert_eq!(ports[1].path, Path::new("/dev/ttyUSB0"));
        assert!(ports[0].usb.is_none());
    }
}
