//! The scenarios on the mailbox: identity, every readable object, parameter writes and their refusals.

use ethercrab::error::Error;
use ethercrab::std::ethercat_now;
use ethercrab::SubDeviceRef;
use std::cell::RefCell;

use firmware::boot::program::Interface;
use firmware::boot::tables::APPLICATION_TABLE;
use firmware::od::access::{AccessContext, CommState, Dictionary, NoApplicationObjects, Table};
use firmware::od::entry::{Access, DataType, Entry, Limits, Storage};
use hal_sim::sim::update::PowerOnObjects;

use super::{abort_code, download, emit, err, upload, Master, Outcome, MAX_SUBDEVICES, PDI_LEN};

thread_local! {
    /// drive-sim's drive and application objects at power-on (factory image, empty parameter store).
    static POWER_ON: RefCell<PowerOnObjects> = RefCell::new(PowerOnObjects::new());
}

/// The dictionary of drive-sim's drive at power-on (node 1, the application table with 0x100A served by program
/// control).
fn dictionary() -> Dictionary {
    POWER_ON.with(|p| Dictionary::with_table(APPLICATION_TABLE, p.borrow().drive.dictionary().values().clone()))
}

/// What the dictionary answers to an SDO upload of `index:sub` over EtherCAT, application entries (0x1010/0x1011,
/// 0x100A, 0x1F5x) through the objects drive-sim serves: the value's bytes (a VISIBLE_STRING up to its first NUL)
/// or the abort code.
pub fn dict_upload(d: &Dictionary, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
    let mut buf = [0u8; 1024];
    let read = POWER_ON.with(|p| p.borrow_mut().read_in(d, Interface::Ethercat, index, sub, 0, &mut buf));
    match read {
        Ok(r) => Ok(buf.get(..r.total_len.min(buf.len())).unwrap_or(&[]).to_vec()),
        Err(a) => Err(a.code()),
    }
}

/// `bytes` as a little-endian unsigned number (at most 8 bytes).
fn le(bytes: &[u8]) -> u64 {
    bytes.iter().rev().fold(0, |acc, b| acc << 8 | u64::from(*b))
}

/// Scenario `identity` (issue 6: "find exactly one slave whose identity matches 0x1018 and the SII"): ethercrab's
/// init finds the SubDevices (a BRD working counter) and reads each one's SII; exactly one, its vendor, product
/// and revision from the SII equal 0x1018:01..03 over SDO and the dictionary, its name (SII general category)
/// equals 0x1008 over SDO and the dictionary.
pub async fn identity(master: &'static Master) -> Outcome {
    let group = master.init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now).await.map_err(err("init"))?;
    emit("subdevices_found", group.len());
    emit("bus_subdevices", master.num_subdevices());
    if group.len() != 1 {
        return Err(format!("{} SubDevices found, expected 1", group.len()));
    }
    let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
    let (state, code) = sd.status().await.map_err(err("AL status"))?;
    emit("state_after_init", format!("{state:?}"));
    emit("al_status_code", format!("{code:?}"));
    let id = sd.identity();
    let sii = [id.vendor_id, id.product_id, id.revision];
    let d = dictionary();
    let mut sdo = [0u32; 3];
    for (k, key) in ["vendor", "product", "revision"].iter().enumerate() {
        let sub = u8::try_from(k + 1).unwrap_or(0);
        let v: u32 = sd.sdo_read(0x1018, sub).await.map_err(err("SDO 0x1018"))?;
        sdo[k] = v;
        let dict = dict_upload(&d, 0x1018, sub).map(|b| le(&b)).map_err(|c| format!("dictionary 0x1018: {c:#x}"))?;
        emit(&format!("sii_{key}"), format!("0x{:08x}", sii[k]));
        emit(&format!("sdo_{key}"), format!("0x{v:08x}"));
        emit(&format!("dict_{key}"), format!("0x{dict:08x}"));
        if u64::from(sii[k]) != dict || u64::from(v) != dict {
            return Err(format!("{key}: SII 0x{:08x}, SDO 0x{v:08x}, dictionary 0x{dict:08x}", sii[k]));
        }
    }
    if sdo[0] == 0 {
        return Err("vendor id 0".to_owned());
    }
    let name = upload(&sd, 0x1008, 0).await.map_err(err("SDO 0x1008"))?;
    let name = String::from_utf8_lossy(&name).into_owned();
    let dict_name = dict_upload(&d, 0x1008, 0).map_err(|c| format!("dictionary 0x1008: {c:#x}"))?;
    let dict_name = String::from_utf8_lossy(&dict_name).into_owned();
    // ethercrab's `name()` is the SII general category's order string (ETG.2010 OrderIdx, the ESI `Type`),
    // its `description()` the name string (NameIdx, the ESI device `Name`): the latter is the device name.
    let description = sd.description().await.map_err(err("SII name string"))?.unwrap_or_default();
    emit("sii_order", sd.name());
    emit("sii_name", description.as_str());
    emit("sdo_device_name", &name);
    emit("dict_device_name", &dict_name);
    if description.as_str() != name || name != dict_name {
        return Err(format!("names differ: SII {description:?}, 0x1008 {name:?}, dictionary {dict_name:?}"));
    }
    group.into_init(master).await.map_err(err("PRE-OP -> INIT"))?;
    emit("init_again", 1);
    Ok(())
}

/// Entries whose value the running drive produces, so that an upload may differ from the default dictionary.
/// The rule: an entry is excluded only if it is read-only (`ro`: "the value may change at run time"; never
/// `rw`, never `const`) **and** the drive measures, counts or derives it on every tick or from the simulated
/// hardware; each is listed with its reason. Every other readable entry must equal the default exactly (value
/// and length, or the same abort code). The scenario fails if an entry listed here is not `ro`.
const MEASURED: &[(u16, u8, &str)] = &[
    (0x1001, 0, "error register: the drive's fault state at start-up (plant supply, feedback)"),
    (0x1C32, 3, "SM2 shift time: measured by the synchronisation"),
    (0x1C32, 6, "SM2 calc and copy time: measured"),
    (0x1C33, 3, "SM3 shift time: measured by the synchronisation"),
    (0x1C33, 6, "SM3 calc and copy time: measured"),
    (0x6041, 0, "statusword: the drive's CiA 402 state machine (bit 9 remote, bit 4 voltage enabled)"),
    (0x6062, 0, "position demand value: follows the actual position while disabled"),
    (0x6063, 0, "position actual internal value: the encoder"),
    (0x6064, 0, "position actual value: the encoder"),
    (0x606B, 0, "velocity demand value: measured loop state"),
    (0x606C, 0, "velocity actual value: encoder noise at standstill"),
    (0x6077, 0, "torque actual value: measured q current"),
    (0x6078, 0, "current actual value: measured"),
    (0x6079, 0, "DC link voltage: measured bus voltage"),
    (0x60F4, 0, "following error: actual minus demand"),
    (0x60FC, 0, "position demand internal value: follows the actual position"),
];

/// Scenario `objects` (issue 6: "read every readable object through SDO and compare it with the dictionary"):
/// in PRE-OP, every entry of the generated table that is readable is uploaded with ethercrab's `sdo_read` into
/// [`super::Raw`] (expedited, normal or segmented as the drive answers) and compared byte for byte with the
/// default dictionary's answer; entries the dictionary refuses (abort) must be refused with the same code.
pub async fn read_all(master: &'static Master) -> Outcome {
    let group = master.init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now).await.map_err(err("init"))?;
    let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
    let d = dictionary();
    for (index, sub, _) in MEASURED {
        let e =
            d.find(*index, *sub).map_err(|a| format!("excluded {index:#06x}:{sub} not in the dictionary: {a:?}"))?;
        if e.access() != Access::ReadOnly {
            return Err(format!("excluded {index:#06x}:{sub} is {:?}, not ro", e.access()));
        }
    }
    let (mut read, mut equal, mut refused_alike, mut excluded_differ, mut longest) = (0u32, 0u32, 0u32, 0u32, 0usize);
    let mut mismatches = Vec::new();
    let started = std::time::Instant::now();
    let mut bytes = 0usize;
    for e in Table::GENERATED.entries() {
        if !e.access().readable() {
            continue;
        }
        read += 1;
        let expected = dict_upload(&d, e.index, e.sub);
        let got = match upload(&sd, e.index, e.sub).await {
            Ok(v) => Ok(v),
            Err(x) => Err(abort_code(&x).map_err(|t| format!("{:#06x}:{}: {t}", e.index, e.sub))?),
        };
        if let Ok(v) = &got {
            longest = longest.max(v.len());
            bytes += v.len();
        }
        let excluded = MEASURED.iter().any(|(i, s, _)| *i == e.index && *s == e.sub);
        match (&expected, &got) {
            (a, b) if a == b => {
                if a.is_ok() {
                    equal += 1;
                } else {
                    refused_alike += 1;
                }
            }
            (Ok(a), Ok(b)) if excluded && a.len() == b.len() => excluded_differ += 1,
            _ => mismatches.push(format!("{:#06x}:{} {} dict {:?} sdo {:?}", e.index, e.sub, e.name, expected, got)),
        }
    }
    let secs = started.elapsed().as_secs_f64();
    emit("entries_read", read);
    emit("entries_equal", equal);
    emit("entries_refused_alike", refused_alike);
    emit("entries_excluded", MEASURED.len());
    emit("excluded_differing", excluded_differ);
    emit("mismatches", mismatches.len());
    emit("longest_upload_bytes", longest);
    emit("upload_bytes_per_s", format!("{:.0}", bytes as f64 / secs.max(1e-9)));
    emit("uploads_s", format!("{secs:.3}"));
    for m in mismatches.iter().take(20) {
        println!("mismatch: {m}");
    }
    group.into_init(master).await.map_err(err("PRE-OP -> INIT"))?;
    if !mismatches.is_empty() {
        return Err(format!("{} entries differ from the dictionary, first: {}", mismatches.len(), mismatches[0]));
    }
    Ok(())
}

/// The integer range of a fixed-size integer type (None for the others and for 64-bit types, which
/// ethercrab's expedited download cannot exceed anyway).
fn type_range(t: DataType) -> Option<(i64, i64)> {
    Some(match t {
        DataType::Unsigned8 => (0, 0xFF),
        DataType::Unsigned16 => (0, 0xFFFF),
        DataType::Unsigned32 => (0, 0xFFFF_FFFF),
        DataType::Integer8 => (-0x80, 0x7F),
        DataType::Integer16 => (-0x8000, 0x7FFF),
        DataType::Integer32 => (-0x8000_0000, 0x7FFF_FFFF),
        _ => return None,
    })
}

/// An expedited download of `value` as `t` (the entry's own type, so its own size).
async fn write_as<S>(sd: &SubDeviceRef<'_, S>, e: &Entry, t: DataType, value: i64) -> Result<(), Error>
where
    S: std::ops::Deref<Target = ethercrab::SubDevice>,
{
    let (i, s) = (e.index, e.sub);
    match t {
        DataType::Unsigned8 => download(sd, i, s, value as u8).await,
        DataType::Unsigned16 => download(sd, i, s, value as u16).await,
        DataType::Unsigned32 => download(sd, i, s, value as u32).await,
        DataType::Integer8 => download(sd, i, s, value as i8).await,
        DataType::Integer16 => download(sd, i, s, value as i16).await,
        _ => download(sd, i, s, value as i32).await,
    }
}

/// `bytes` (little-endian, `t`'s size) as a signed number.
fn value_of(t: DataType, bytes: &[u8]) -> i64 {
    let raw = le(bytes);
    match t {
        DataType::Integer8 => i64::from(raw as u8 as i8),
        DataType::Integer16 => i64::from(raw as u16 as i16),
        DataType::Integer32 => i64::from(raw as u32 as i32),
        _ => raw as i64,
    }
}

/// The parameters the scenario writes: for each integer type, the first `rw` entry from 0x2000 up kept in RAM
/// whose limits are narrower than its type on at least one side (so that an out-of-range value can be sent in
/// the entry's own size).
fn chosen_parameters() -> Vec<(&'static Entry, i64, i64)> {
    let mut out = Vec::new();
    for t in [
        DataType::Unsigned8,
        DataType::Unsigned16,
        DataType::Unsigned32,
        DataType::Integer8,
        DataType::Integer16,
        DataType::Integer32,
    ] {
        let Some((tmin, tmax)) = type_range(t) else { continue };
        let found = Table::GENERATED.entries().iter().find_map(|e| {
            if e.data_type != t || e.access() != Access::ReadWrite || e.index < 0x2000 {
                return None;
            }
            if !matches!(e.storage, Storage::Ram { .. }) {
                return None;
            }
            let (min, max) = match *e.generated_limits() {
                Limits::Signed { min, max } => (i64::from(min), i64::from(max)),
                Limits::Unsigned { min, max } => (i64::from(min), i64::from(max)),
                _ => return None,
            };
            (min > tmin || max < tmax).then_some((e, min, max))
        });
        out.extend(found);
    }
    out
}

/// Scenario `parameters` (issue 6: "write and read back parameters"; "SDO requests for missing objects or with
/// wrong sizes ... answered with the right CoE abort code"): in PRE-OP with the drive disabled, one parameter
/// of each integer type is written and read back, then refused writes (out of range, read-only, const, missing
/// object, missing sub-index, too short, too long, not one of the listed values) each return the CiA 301 abort
/// code (ethercrab's `MailboxError::Aborted { code }`) and leave the value as it was; the dictionary, asked
/// the same write in the same state, gives the same code. Every parameter is restored at the end.
pub async fn parameters(master: &'static Master) -> Outcome {
    let group = master.init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now).await.map_err(err("init"))?;
    let sd = group.subdevice(master, 0).map_err(err("SubDevice 0"))?;
    let mut d = dictionary();
    let ctx = AccessContext { comm_state: CommState::PreOperational, power_stage_enabled: false, max_pdo_bytes: 40 };
    let chosen = chosen_parameters();
    emit("parameters_written", chosen.len());
    if chosen.len() < 4 {
        return Err(format!("only {} parameters to write", chosen.len()));
    }
    // 1. Writes that must succeed, read back through an upload.
    for (e, min, max) in &chosen {
        let before = upload(&sd, e.index, e.sub).await.map_err(err("upload"))?;
        let old = value_of(e.data_type, &before);
        let new = if old < *max { old + 1 } else { old - 1 }.clamp(*min, *max);
        write_as(&sd, e, e.data_type, new)
            .await
            .map_err(|x| format!("write {:#06x}:{} = {new}: {x}", e.index, e.sub))?;
        let after = value_of(e.data_type, &upload(&sd, e.index, e.sub).await.map_err(err("upload"))?);
        emit(
            &format!("write_{:04x}_{:02x}", e.index, e.sub),
            format!("{old}->{new}->{after} ({:?} {})", e.data_type, e.name),
        );
        if after != new {
            return Err(format!("{:#06x}:{} wrote {new}, read back {after}", e.index, e.sub));
        }
        write_as(&sd, e, e.data_type, old).await.map_err(err("restore"))?;
    }
    // 2. Writes that must be refused: (case, entry, type written, value, CiA 301 abort code).
    let (e_hi, _, max_hi) = *chosen
        .iter()
        .find(|(e, _, max)| type_range(e.data_type).is_some_and(|(_, t)| *max < t))
        .ok_or("no parameter below its type's maximum")?;
    let u32_entry =
        chosen.iter().map(|c| c.0).find(|e| e.data_type == DataType::Unsigned32).ok_or("no UNSIGNED32 parameter")?;
    let u8_entry =
        chosen.iter().map(|c| c.0).find(|e| e.data_type == DataType::Unsigned8).ok_or("no UNSIGNED8 parameter")?;
    let statusword = d.find(0x6041, 0).map_err(|a| format!("0x6041: {a:?}"))?;
    let vendor = d.find(0x1018, 1).map_err(|a| format!("0x1018:01: {a:?}"))?;
    let option = d.find(0x6007, 0).map_err(|a| format!("0x6007: {a:?}"))?;
    if d.object(0x5FFF).is_some() || d.find(0x1018, 0x7F).is_ok() {
        return Err("0x5FFF or 0x1018:7F exists: pick another missing object".to_owned());
    }
    let missing_object = Entry { index: 0x5FFF, sub: 0, ..*u32_entry };
    let missing_sub = Entry { index: 0x1018, sub: 0x7F, ..*u32_entry };
    let cases: [(&str, &Entry, DataType, i64, u32); 8] = [
        ("out_of_range", e_hi, e_hi.data_type, max_hi + 1, 0x0609_0031),
        ("read_only", statusword, DataType::Unsigned16, 0x0F, 0x0601_0002),
        ("const", vendor, DataType::Unsigned32, 1, 0x0601_0002),
        ("missing_object", &missing_object, DataType::Unsigned32, 1, 0x0602_0000),
        ("missing_sub", &missing_sub, DataType::Unsigned32, 1, 0x0609_0011),
        ("too_short", u32_entry, DataType::Unsigned16, 1, 0x0607_0013),
        ("too_long", u8_entry, DataType::Unsigned32, 1, 0x0607_0012),
        ("not_listed", option, DataType::Integer16, 9, 0x0609_0030),
    ];
    for (case, e, t, value, expected) in cases {
        let before = upload(&sd, e.index, e.sub).await;
        let res = write_as(&sd, e, t, value).await;
        let code = match &res {
            Ok(()) => return Err(format!("{case}: {:#06x}:{} = {value} was accepted", e.index, e.sub)),
            Err(x) => abort_code(x).map_err(|t| format!("{case}: {t}"))?,
        };
        // The dictionary asked the same write (the same bytes) in the same state.
        let size = match t {
            DataType::Unsigned8 | DataType::Integer8 => 1,
            DataType::Unsigned16 | DataType::Integer16 => 2,
            _ => 4,
        };
        let bytes = value.to_le_bytes();
        let dict_code = match d.write(e.index, e.sub, &bytes[..size], ctx, &mut NoApplicationObjects) {
            Ok(()) => 0,
            Err(a) => a.code(),
        };
        let after = upload(&sd, e.index, e.sub).await;
        let unchanged = match (&before, &after) {
            (Ok(a), Ok(b)) => a == b,
            (Err(a), Err(b)) => abort_code(a).ok() == abort_code(b).ok(),
            _ => false,
        };
        emit(&format!("abort_{case}"), format!("0x{code:08x}"));
        emit(&format!("dict_abort_{case}"), format!("0x{dict_code:08x}"));
        emit(&format!("unchanged_{case}"), u8::from(unchanged));
        if code != expected || dict_code != expected {
            return Err(format!(
                "{case}: abort 0x{code:08x} (dictionary 0x{dict_code:08x}), expected 0x{expected:08x}"
            ));
        }
        if !unchanged {
            return Err(format!("{case}: the value changed ({before:?} -> {after:?})"));
        }
    }
    group.into_init(master).await.map_err(err("PRE-OP -> INIT"))?;
    Ok(())
}
