//! EtherCAT (`--ecat IFACE`): the drives on a segment through a raw socket, with `ethercrab` as the master
//! library. ethercrab finds the SubDevices, gives them station addresses (0x1000 + position), reads their SII
//! (identity, name, mailbox) and takes them to PRE-OP; the tool then talks to each through its mailbox with its
//! own CoE SDO client ([`coe`]: expedited, normal and segmented transfers, complete access, emergencies kept
//! aside) and FoE ([`foe`], the firmware download in BOOT), and changes the EtherCAT state itself (AL control).
//!
//! Drives are addressed by their position on the segment, 1 for the first (`--node`), or by station address
//! (`--station`). The tool exchanges no process data: SAFE-OP and OP, which need it, are refused with a reason.

pub mod coe;
pub mod foe;
pub mod mailbox;

use std::time::{Duration, Instant};

use ethercrab::std::{ethercat_now, tx_rx_task};
use ethercrab::{Command, MainDevice, MainDeviceConfig, PduStorage, Timeouts};
use serde_json::json;

use crate::link::{DriveLink, StateCommand};
use crate::sdo::SdoError;
use mailbox::Mailbox;

/// Most SubDevices on one segment (a power of two, ethercrab's storage rule).
const MAX_SUBDEVICES: usize = 64;
/// Process image bytes of the group (none is exchanged; ethercrab wants room for the PDI it would map).
const PDI_LEN: usize = 2048;
/// Largest PDU payload: a full Ethernet frame.
const MAX_PDU_DATA: usize = PduStorage::element_size(1100);
/// Frames in flight at once.
const MAX_FRAMES: usize = 16;
/// ethercrab's frame storage, split once per process into the TX/RX handles and the PDU loop.
static PDU_STORAGE: PduStorage<MAX_FRAMES, MAX_PDU_DATA> = PduStorage::new();

/// ESC registers (ETG.1000.4 §6): AL control, AL status, AL status code.
const AL_CONTROL: u16 = 0x0120;
const AL_STATUS: u16 = 0x0130;
const AL_STATUS_CODE: u16 = 0x0134;
/// AL states (ETG.1000.6 §6.4.1).
pub const INIT: u8 = 0x01;
/// PRE-OPERATIONAL.
pub const PRE_OP: u8 = 0x02;
/// BOOTSTRAP.
pub const BOOT: u8 = 0x03;
/// SII words of the bootstrap mailbox (ETG.1000.6 Table 16: receive offset/size, send offset/size).
const SII_BOOTSTRAP_MAILBOX: u16 = 0x0014;

/// The name of AL state `state` (bits 3..0 of AL status) and the error flag (bit 4).
pub fn al_state_name(status: u16) -> String {
    let name = match status & 0x0F {
        0x01 => "INIT",
        0x02 => "PRE-OP",
        0x03 => "BOOT",
        0x04 => "SAFE-OP",
        0x08 => "OP",
        _ => "unknown",
    };
    if status & 0x10 != 0 {
        format!("{name} (error)")
    } else {
        name.to_owned()
    }
}

/// A drive on the segment as ethercrab's init found it.
#[derive(Clone, Debug)]
pub struct Drive {
    /// Configured station address.
    pub station: u16,
    /// Station alias (SII / register 0x0012).
    pub alias: u16,
    /// The SII's device name.
    pub name: String,
    /// The SII's identity: vendor, product, revision, serial.
    pub identity: [u32; 4],
    /// The bootstrap mailbox from the SII: receive (start, length), send (start, length).
    pub boot_mailbox: [(u16, u16); 2],
}

/// The EtherCAT link.
pub struct EcatLink {
    master: &'static MainDevice<'static>,
    drives: Vec<Drive>,
    timeout: Duration,
    /// The mailbox counter of each drive (by position), 1..7.
    counters: Vec<u8>,
    /// The mailbox layout of each drive (by position) once read: SM0/SM1 change only with the AL state.
    layouts: Vec<Option<mailbox::Layout>>,
    /// CoE emergencies received while waiting for answers.
    pub emergencies: Vec<[u8; 8]>,
}

/// ethercrab's timeouts: state changes get 5 s, mailbox answers the SDO timeout, a datagram 500 ms (a segment
/// answers in microseconds; a simulator on a loaded host may take far longer, and a tool can afford to wait).
fn timeouts(sdo: Duration) -> Timeouts {
    Timeouts {
        state_transition: Duration::from_secs(5),
        pdu: Duration::from_millis(500),
        eeprom: Duration::from_millis(50),
        wait_loop_delay: Duration::from_millis(0),
        mailbox_echo: Duration::from_millis(500),
        mailbox_response: sdo,
    }
}

fn block_on<T>(future: impl std::future::Future<Output = T>) -> T {
    async_io::block_on(future)
}

impl EcatLink {
    /// Opens `iface` (a raw socket: root or CAP_NET_RAW) and finds the drives, waiting up to `wait` for a first
    /// answer on the segment.
    pub fn open(iface: &str, timeout: Duration, wait: Duration) -> Result<Self, String> {
        let (tx, rx, pdu_loop) =
            PDU_STORAGE.try_split().map_err(|_| "ethercrab's PDU storage split twice".to_owned())?;
        let task = tx_rx_task(iface, tx, rx).map_err(|e| {
            let hint = if e.kind() == std::io::ErrorKind::PermissionDenied {
                "; a raw socket needs root or CAP_NET_RAW (`sudo setcap cap_net_raw+ep drive-tool`)"
            } else {
                ""
            };
            format!("--ecat {iface}: cannot open a raw socket: {e}{hint}")
        })?;
        std::thread::Builder::new()
            .name("ecat-tx-rx".into())
            .spawn(move || {
                if let Err(e) = async_io::block_on(task) {
                    eprintln!("drive-tool: EtherCAT tx/rx on the interface ended: {e}");
                }
            })
            .map_err(|e| format!("spawn the EtherCAT tx/rx thread: {e}"))?;
        let master: &'static MainDevice<'static> = Box::leak(Box::new(MainDevice::new(
            pdu_loop,
            timeouts(timeout),
            MainDeviceConfig { dc_static_sync_iterations: 0, ..MainDeviceConfig::default() },
        )));
        let mut link = Self {
            master,
            drives: Vec::new(),
            timeout,
            counters: Vec::new(),
            layouts: Vec::new(),
            emergencies: Vec::new(),
        };
        link.find(wait)?;
        Ok(link)
    }

    /// (Re)runs ethercrab's init: station addresses, SII, mailboxes, PRE-OP. An empty segment (no answer to a
    /// broadcast read within `wait`) leaves no drives.
    fn find(&mut self, wait: Duration) -> Result<(), String> {
        let master = self.master;
        let drives = block_on(async {
            let deadline = Instant::now() + wait;
            loop {
                // ESC type register (0x0000): every ESC on the segment adds one to the working counter.
                // (ethercrab tells the working counter through its check: expecting 0, a segment with drives fails
                // the check.)
                let answered = match Command::brd(0x0000).receive_slice(master, 1).await {
                    Ok(pdu) => match pdu.wkc(0) {
                        Ok(_) => Ok(0),
                        Err(ethercrab::error::Error::WorkingCounter { received, .. }) => Ok(received),
                        Err(e) => Err(e),
                    },
                    Err(e) => Err(e),
                };
                match answered {
                    Ok(n) if n > 0 => break,
                    _ if Instant::now() < deadline => {
                        async_io::Timer::after(Duration::from_millis(50)).await;
                    }
                    Ok(_) => return Ok(Vec::new()),
                    Err(e) => {
                        return Err(format!(
                            "no EtherCAT frame came back within {wait:?} ({e}): no drive on the interface, or no link"
                        ))
                    }
                }
            }
            let group = master
                .init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now)
                .await
                .map_err(|e| format!("EtherCAT init (addresses, SII, PRE-OP): {e}"))?;
            let mut drives = Vec::new();
            for sd in group.iter(master) {
                let mut words = [0u8; 8];
                sd.eeprom_read_raw(master, SII_BOOTSTRAP_MAILBOX, &mut words)
                    .await
                    .map_err(|e| format!("station 0x{:04X}: SII bootstrap mailbox: {e}", sd.configured_address()))?;
                let w = |k: usize| u16::from_le_bytes([words[2 * k], words[2 * k + 1]]);
                let id = sd.identity();
                drives.push(Drive {
                    station: sd.configured_address(),
                    alias: sd.alias_address(),
                    name: sd.name().to_owned(),
                    identity: [id.vendor_id, id.product_id, id.revision, id.serial],
                    boot_mailbox: [(w(0), w(1)), (w(2), w(3))],
                });
            }
            Ok(drives)
        })?;
        self.counters = vec![0; drives.len()];
        self.layouts = vec![None; drives.len()];
        self.drives = drives;
        Ok(())
    }

    /// The position (1-based) of the drive with station address or alias `station`.
    pub fn position_of_station(&self, station: u16) -> Result<u8, String> {
        self.drives
            .iter()
            .position(|d| d.station == station || (d.alias != 0 && d.alias == station))
            .map(|p| p as u8 + 1)
            .ok_or_else(|| {
                let have: Vec<String> = self.drives.iter().map(|d| format!("0x{:04X}", d.station)).collect();
                format!("no drive with station address or alias 0x{station:04X} (found: {})", have.join(", "))
            })
    }

    fn drive(&self, node: u8) -> Result<(usize, &Drive), String> {
        let index = usize::from(node)
            .checked_sub(1)
            .filter(|&i| i < self.drives.len())
            .ok_or_else(|| format!("no drive at position {node}: {} found on the segment", self.drives.len()))?;
        Ok((index, &self.drives[index]))
    }

    /// Runs `f` with the mailbox of the drive at position `node`.
    fn with_mailbox<T, E: From<String>>(
        &mut self,
        node: u8,
        f: impl for<'m> AsyncFnOnce(&'m mut Mailbox<'_>) -> Result<T, E>,
    ) -> Result<T, E> {
        let (index, drive) = self.drive(node).map_err(E::from)?;
        let station = drive.station;
        let master = self.master;
        let timeout = self.timeout;
        let counter = &mut self.counters[index];
        let layout = &mut self.layouts[index];
        let emergencies = &mut self.emergencies;
        block_on(async move {
            let mut mbx =
                Mailbox::open(master, station, *layout, timeout, counter, emergencies).await.map_err(E::from)?;
            *layout = Some(mbx.layout());
            f(&mut mbx).await
        })
    }

    /// AL status of the drive at `node`.
    pub fn al_status(&self, node: u8) -> Result<u16, String> {
        let station = self.drive(node)?.1.station;
        block_on(read_u16(self.master, station, AL_STATUS))
    }

    /// Requests AL state `state` of the drive at `node` and waits for it; a refusal names the AL status code.
    pub fn request_state(&self, node: u8, state: u8) -> Result<(), String> {
        let station = self.drive(node)?.1.station;
        block_on(request_state(self.master, station, state, Duration::from_secs(5)))
    }

    /// Uploads the whole object `index` with one complete access from sub-index 0 (ETG.1000.6 §5.6.2.1.2).
    pub fn upload_complete(&mut self, node: u8, index: u16) -> Result<Vec<u8>, SdoError> {
        self.with_mailbox(node, async |m| coe::upload(m, index, 0, true).await)
    }

    /// The firmware download of the seeds (E4 Table 4-29): INIT; the SII's bootstrap mailbox into SM0/SM1 where it
    /// differs from the standard one; BOOT; FoE write of `file` as `name` with `password`; INIT. The drive
    /// restarts into a complete, verified image when it leaves BOOT; the tool then runs the init again and waits
    /// up to `restart` for the drive to be back in PRE-OP. A refusal (FoE error) leaves the old firmware: the tool
    /// takes the drive back to PRE-OP and returns the refusal.
    pub fn foe_update(
        &mut self,
        node: u8,
        name: &[u8],
        password: u32,
        file: &[u8],
        restart: Duration,
        progress: &mut dyn FnMut(usize),
    ) -> Result<(), String> {
        let (_, drive) = self.drive(node)?;
        let station = drive.station;
        let [boot_receive, boot_send] = drive.boot_mailbox;
        if boot_receive.1 < 16 || boot_send.1 < 16 {
            return Err(format!("station 0x{station:04X}: no bootstrap mailbox in its SII (no FoE download in BOOT)"));
        }
        let master = self.master;
        block_on(async {
            request_state(master, station, INIT, Duration::from_secs(5)).await.map_err(|e| format!("INIT: {e}"))?;
            for (sm, (start, len)) in [(0u16, boot_receive), (1, boot_send)] {
                let now = Command::fprd(station, 0x0800 + 8 * sm)
                    .with_wkc(1)
                    .receive::<[u8; 4]>(master)
                    .await
                    .map_err(|e| format!("SM{sm}: {e}"))?;
                if now[..] != [start.to_le_bytes(), len.to_le_bytes()].concat()[..] {
                    set_sync_manager(master, station, sm, start, len).await?;
                }
            }
            request_state(master, station, BOOT, Duration::from_secs(5)).await.map_err(|e| format!("BOOT: {e}"))
        })?;
        // BOOT has its own mailbox layout: read it afresh, and again after leaving BOOT.
        self.layouts.iter_mut().for_each(|l| *l = None);
        let written = self.with_mailbox(node, async |m| {
            foe::write(m, name, password, file, progress).await.map_err(|e| e.to_string())
        });
        // Leaving BOOT ends the download either way: a complete image is activated (the drive restarts), anything
        // else lets the old application run again.
        let left = block_on(request_state(master, station, INIT, Duration::from_secs(5)));
        self.layouts.iter_mut().for_each(|l| *l = None);
        if let Err(refused) = written {
            self.find(restart)?;
            return Err(match left {
                Ok(()) => refused,
                Err(e) => format!("{refused}; leaving BOOT: {e}"),
            });
        }
        self.wait_back(node, restart)
    }

    /// Runs the init until the drive at `node` is back (PRE-OP) or `limit` passed.
    fn wait_back(&mut self, node: u8, limit: Duration) -> Result<(), String> {
        let deadline = Instant::now() + limit;
        let mut last = String::new();
        while Instant::now() < deadline {
            match self.find(Duration::from_millis(500)) {
                Ok(()) if self.drives.len() >= usize::from(node) => {
                    if self.al_status(node).map(|s| s & 0x1F) == Ok(u16::from(PRE_OP)) {
                        return Ok(());
                    }
                }
                Ok(()) => last = format!("{} drives on the segment", self.drives.len()),
                Err(e) => last = e,
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        Err(format!("the drive at position {node} was not back in PRE-OP within {limit:?}: {last}"))
    }
}

async fn read_u16(master: &MainDevice<'_>, station: u16, register: u16) -> Result<u16, String> {
    Command::fprd(station, register)
        .with_wkc(1)
        .receive::<u16>(master)
        .await
        .map_err(|e| format!("station 0x{station:04X} register 0x{register:04X}: {e}"))
}

/// Writes AL control and waits for AL status to show `state`; an error flag ends the wait with the AL status code
/// (and acknowledges it, so that the drive takes the next request).
async fn request_state(master: &MainDevice<'_>, station: u16, state: u8, limit: Duration) -> Result<(), String> {
    Command::fpwr(station, AL_CONTROL)
        .with_wkc(1)
        .send(master, u16::from(state))
        .await
        .map_err(|e| format!("station 0x{station:04X} AL control: {e}"))?;
    let deadline = Instant::now() + limit;
    loop {
        let status = read_u16(master, station, AL_STATUS).await?;
        if status & 0x1F == u16::from(state) {
            return Ok(());
        }
        if status & 0x10 != 0 {
            let code = read_u16(master, station, AL_STATUS_CODE).await.unwrap_or(0);
            let _ = Command::fpwr(station, AL_CONTROL).send(master, (status & 0x0F) | 0x10).await;
            return Err(format!(
                "the drive stays in {} with AL status code 0x{code:04X} ({})",
                al_state_name(status & 0x0F),
                al_status_code_text(code)
            ));
        }
        if Instant::now() >= deadline {
            return Err(format!("still {} after {limit:?}", al_state_name(status)));
        }
        async_io::Timer::after(Duration::from_millis(1)).await;
    }
}

/// The text of AL status code `code` (ETG.1000.6 Table 11), as ethercrab names them.
fn al_status_code_text(code: u16) -> String {
    use ethercrab::EtherCrabWireRead as _;
    match ethercrab::AlStatusCode::unpack_from_slice(&code.to_le_bytes()) {
        Ok(c) => c.to_string(),
        Err(_) => "unknown".into(),
    }
}

/// Configures SM `sm` at `start` with `len` bytes, disabled while it changes (an ESC ignores a new layout of an
/// active sync manager).
async fn set_sync_manager(master: &MainDevice<'_>, station: u16, sm: u16, start: u16, len: u16) -> Result<(), String> {
    let base = 0x0800 + 8 * sm;
    let e = |what: &'static str| move |err| format!("SM{sm} {what}: {err}");
    Command::fpwr(station, base + 6).with_wkc(1).send(master, 0u8).await.map_err(e("disable"))?;
    Command::fpwr(station, base)
        .with_wkc(1)
        .send(master, [start.to_le_bytes(), len.to_le_bytes()].concat().as_slice())
        .await
        .map_err(e("layout"))?;
    Command::fpwr(station, base + 6).with_wkc(1).send(master, 1u8).await.map_err(e("enable"))
}

impl DriveLink for EcatLink {
    fn upload(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        self.with_mailbox(node, async |m| coe::upload(m, index, sub, false).await)
    }

    fn download(&mut self, node: u8, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        self.with_mailbox(node, async |m| coe::download(m, index, sub, data, false, &mut |_| {}).await)
    }

    /// CoE has no block transfer: a large object comes by the normal upload and its segments.
    fn upload_bulk(&mut self, node: u8, index: u16, sub: u8) -> Result<Vec<u8>, SdoError> {
        self.upload(node, index, sub)
    }

    fn download_bulk(
        &mut self,
        node: u8,
        index: u16,
        sub: u8,
        data: &[u8],
        progress: &mut dyn FnMut(usize),
    ) -> Result<(), SdoError> {
        self.with_mailbox(node, async |m| coe::download(m, index, sub, data, false, progress).await)
    }

    fn lss(&mut self, _request: [u8; 8], _wait: Duration) -> Result<Vec<[u8; 8]>, String> {
        Err("LSS is a CANopen service: on EtherCAT the master addresses drives by position and station address".into())
    }

    fn expect_boot_up(&mut self, _node: u8) {}

    fn wait_boot_up(&mut self, node: u8, timeout: Duration) -> Result<bool, String> {
        Ok(self.wait_back(node, timeout).is_ok())
    }

    fn scan(&mut self, _timeout: Duration) -> Result<Vec<u8>, String> {
        Ok((1..=self.drives.len().min(usize::from(u8::MAX)) as u8).collect())
    }

    fn command_state(&mut self, node: u8, command: StateCommand, _timeout: Duration) -> Result<bool, String> {
        let positions: Vec<u8> = if node == 0 { self.scan(Duration::ZERO)? } else { vec![node] };
        let state = match command {
            StateCommand::Preop => PRE_OP,
            StateCommand::Stop => INIT,
            StateCommand::Start => {
                return Err("OP (and SAFE-OP) need process data, which drive-tool does not exchange: a PLC or an \
                            EtherCAT master with a process-data cycle takes the drive there"
                    .into())
            }
            StateCommand::Reset | StateCommand::ResetComm => {
                return Err("EtherCAT has no reset service; `nmt stop` (INIT) then `nmt preop` restarts the \
                            communication"
                    .into())
            }
        };
        for position in positions {
            self.request_state(position, state)?;
        }
        Ok(true)
    }

    fn comm_state(&self, node: u8) -> Option<String> {
        self.al_status(node).ok().map(al_state_name)
    }

    fn comm_state_key(&self) -> &'static str {
        "al_state"
    }

    fn describe(&mut self, node: u8) -> Vec<(&'static str, serde_json::Value, String)> {
        let Ok((_, d)) = self.drive(node) else { return Vec::new() };
        let [vendor, product, revision, _] = d.identity;
        vec![
            ("station", json!(d.station), format!("0x{:04X}", d.station)),
            ("alias", json!(d.alias), format!("0x{:04X}", d.alias)),
            ("sii_name", json!(d.name), d.name.clone()),
            ("sii_vendor_id", json!(vendor), format!("0x{vendor:08X}")),
            ("sii_product_code", json!(product), format!("0x{product:08X}")),
            ("sii_revision", json!(revision), format!("0x{revision:08X}")),
        ]
    }

    fn ecat(&mut self) -> Option<&mut EcatLink> {
        Some(self)
    }
}
