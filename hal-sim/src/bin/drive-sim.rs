//! `drive-sim`: runs the firmware against the simulated drive.
fn main() {
    println!("drive-sim");
}
