//! od-gen command line.
//!
//! - `od-gen summary [path]`: validates the description (default `firmware/device.toml` of this workspace) and
//!   prints what it holds and how long validation and generation took.
//! - `od-gen generate <path> <out_dir>`: writes every generated file into `out_dir`, as `firmware/build.rs` does.
//!
//! Both print the full report and exit with status 1 when the description has mistakes.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use od_gen::model::{Area, Description, StorageKind};

const USAGE: &str = "usage: od-gen summary [device.toml]\n       od-gen generate <device.toml> <out_dir>";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let default_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware/device.toml");
    let result = match args.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
        ["summary"] => summary(&default_path),
        ["summary", path] => summary(Path::new(path)),
        ["generate", path, out_dir] => generate(Path::new(path), Path::new(out_dir)),
        _ => Err(USAGE.to_string()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(report) => {
            eprintln!("{report}");
            ExitCode::FAILURE
        }
    }
}

fn generate(path: &Path, out_dir: &Path) -> Result<(), String> {
    std::fs::create_dir_all(out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    od_gen::generate_all(path, out_dir)?;
    println!("generated from {} into {}", path.display(), out_dir.display());
    Ok(())
}

fn summary(path: &Path) -> Result<(), String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    let start = Instant::now();
    let d = od_gen::load_str(&text, &path.display().to_string())?;
    let validated = start.elapsed();
    let files = od_gen::render(&d)?;
    let total = start.elapsed();
    print_summary(&PathBuf::from(path), &d);
    println!("generated files:");
    for (name, contents) in &files {
        println!("  {name:<22} {:>8} bytes", contents.len());
    }
    println!(
        "time: parse+validate {:.2} ms, generation {:.2} ms, total {:.2} ms",
        validated.as_secs_f64() * 1e3,
        (total - validated).as_secs_f64() * 1e3,
        total.as_secs_f64() * 1e3
    );
    Ok(())
}

fn print_summary(path: &Path, d: &Description) {
    let entries: usize = d.objects.iter().map(|o| o.subs.len()).sum();
    println!(
        "{}: {} ({}), {} objects, {entries} entries",
        path.display(),
        d.device.device_name,
        d.device.order_code,
        d.objects.len()
    );
    for area in Area::ALL {
        let objects: Vec<_> = d.objects.iter().filter(|o| Area::of(o.index) == area).collect();
        if !objects.is_empty() {
            let n: usize = objects.iter().map(|o| o.subs.len()).sum();
            println!("  {:<55} {:>4} objects {:>5} entries", area.title(), objects.len(), n);
        }
    }
    let mut storage: BTreeMap<&str, usize> = BTreeMap::new();
    let mut persistent = 0;
    let mut mappable = 0;
    let mut handles = Vec::new();
    for o in &d.objects {
        for s in &o.subs {
            *storage.entry(s.storage.word()).or_default() += 1;
            persistent += usize::from(s.persistent);
            mappable += usize::from(s.pdo != od_gen::model::PdoMapping::No);
            if let Some(h) = &s.handle {
                handles.push(format!("{h} (0x{:04X}:{:02X})", o.index, s.sub));
            }
        }
    }
    let per_storage: Vec<String> = storage.iter().map(|(k, n)| format!("{k} {n}")).collect();
    println!("  storage: {}", per_storage.join(", "));
    match od_gen::rust_gen::ram_layout(d) {
        Ok(layout) => println!("  RAM value bytes: {} ({} RAM entries)", layout.value_bytes, layout.slots.len()),
        Err(e) => println!("  RAM value bytes: layout failed: {e}"),
    }
    let persistent_bytes: usize = d
        .objects
        .iter()
        .flat_map(|o| o.subs.iter())
        .filter(|s| s.persistent && s.storage == StorageKind::Ram)
        .map(|s| s.data_type.fixed_size().or(s.length).unwrap_or(0))
        .sum();
    println!("  persistent entries: {persistent} ({persistent_bytes} value bytes)");
    println!("  PDO-mappable entries: {mappable}");
    println!("  handles ({}): {}", handles.len(), handles.join(", "));
}
