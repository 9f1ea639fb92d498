//! Validation error messages: one fixture per kind of mistake (tests/fixtures/errors/<name>.toml), each test
//! asserting that the report names the file, the object (index, sub-index, name) and the reason.
//!
//! The error fixtures hold only objects; `tests/fixtures/device-header.toml` is prepended unless a fixture is
//! standalone (it has its own `[device]` table or says "standalone" in its first line).

use std::fs;
use std::path::PathBuf;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

fn path_of(name: &str) -> String {
    format!("tests/fixtures/errors/{name}.toml")
}

/// The report lines for fixture `name`; panics if the fixture validates.
fn report(name: &str) -> Vec<String> {
    let body = fs::read_to_string(fixtures().join("errors").join(format!("{name}.toml"))).expect("fixture");
    let standalone = body.lines().take_while(|l| l.starts_with('#')).any(|l| l.contains("standalone"))
        || body.lines().any(|l| l.trim() == "[device]");
    let text = if standalone {
        body
    } else {
        let header = fs::read_to_string(fixtures().join("device-header.toml")).expect("header fixture");
        format!("{header}\n{body}")
    };
    match od_gen::load_str(&text, &path_of(name)) {
        Ok(_) => panic!("{name}: the fixture validated, but a mistake was expected"),
        Err(report) => report.lines().map(str::to_string).collect(),
    }
}

/// Fixture `name` yields exactly one line: `<path>: <at>: ...<reason>...`.
fn expect(name: &str, at: &str, reason: &str) {
    let lines = report(name);
    let prefix = format!("{}: {at}: ", path_of(name));
    assert!(
        lines.len() == 1 && lines[0].starts_with(&prefix) && lines[0].contains(reason),
        "{name}: expected exactly one line `{prefix}...{reason}...`, got:\n{}",
        lines.join("\n")
    );
}

#[test]
fn duplicate_index() {
    expect("duplicate_index", "object 0x2000 'Second'", "duplicate index (already declared as 'First')");
}

#[test]
fn duplicate_sub() {
    expect("duplicate_sub", "object 0x2001:01 'B'", "duplicate sub-index (already declared as 'A')");
}

#[test]
fn missing_sub0() {
    expect("missing_sub0", "object 0x2002 'Rec'", "missing sub 0");
}

#[test]
fn sub0_not_highest() {
    expect(
        "sub0_not_highest",
        "object 0x2003:00 'Highest sub-index supported'",
        "sub 0 default 3 is not the highest sub-index 2",
    );
}

#[test]
fn writable_sub0_above_highest() {
    expect(
        "writable_sub0_above_highest",
        "object 0x2003:00 'Highest sub-index supported'",
        "sub 0 default 3 exceeds the highest sub-index 2",
    );
}

#[test]
fn sub0_not_unsigned8() {
    expect(
        "sub0_not_unsigned8",
        "object 0x2003:00 'Highest sub-index supported'",
        "sub 0 must be UNSIGNED8, not UNSIGNED16",
    );
}

#[test]
fn var_with_subs() {
    expect("var_with_subs", "object 0x2004 'Var'", "a VAR declares its value on the object itself");
}

#[test]
fn var_with_nonzero_sub() {
    let lines = report("var_with_nonzero_sub");
    let path = path_of("var_with_nonzero_sub");
    assert!(
        lines.contains(&format!("{path}: object 0x2005:03 'Three': a VAR has only sub-index 0, not 3")),
        "{lines:#?}"
    );
}

#[test]
fn value_attribute_on_record() {
    expect(
        "value_attribute_on_record",
        "object 0x2006 'Rec'",
        "'type' belongs in [[object.sub]] for an ARRAY or RECORD",
    );
}

#[test]
fn array_mixed_types() {
    expect(
        "array_mixed_types",
        "object 0x2007:02 'E2'",
        "ARRAY element type INTEGER16 differs from UNSIGNED32 of sub 1",
    );
}

#[test]
fn unknown_type() {
    expect("unknown_type", "object 0x2008:00 'Thing'", "unknown type 'UINT16'");
}

#[test]
fn unknown_access() {
    expect("unknown_access", "object 0x2009:00 'Thing'", "unknown access 'rwx'");
}

#[test]
fn unknown_pdo() {
    expect("unknown_pdo", "object 0x200A:00 'Thing'", "unknown pdo 'yes'");
}

#[test]
fn unknown_writable_in() {
    expect("unknown_writable_in", "object 0x200B:00 'Thing'", "unknown writable_in 'op'");
}

#[test]
fn unknown_storage() {
    expect("unknown_storage", "object 0x200C:00 'Thing'", "unknown storage 'flash'");
}

#[test]
fn unknown_code() {
    expect("unknown_code", "object 0x200D 'Thing'", "unknown code 'DEFSTRUCT'");
}

#[test]
fn unknown_key() {
    expect("unknown_key", "object 0x200E 'Thing'", "unknown key 'persistant'");
}

#[test]
fn default_outside_min_max() {
    expect("default_outside_min_max", "object 0x2010:00 'Limited'", "default 20 is outside min..max 0..=10");
}

#[test]
fn default_outside_type_range() {
    expect(
        "default_outside_type_range",
        "object 0x2011:00 'Small'",
        "default 300 is outside the UNSIGNED8 range 0..=255",
    );
}

#[test]
fn default_not_in_values() {
    expect("default_not_in_values", "object 0x2012:00 'Option'", "default 3 is not one of values [0, 1, 2, 5, 6]");
}

#[test]
fn min_greater_than_max() {
    expect("min_greater_than_max", "object 0x2013:00 'Limited'", "min 10 is greater than max 5");
}

#[test]
fn min_outside_type_range() {
    expect("min_outside_type_range", "object 0x2014:00 'Limited'", "min -1 is outside the UNSIGNED8 range 0..=255");
}

#[test]
fn values_on_string() {
    expect("values_on_string", "object 0x2015:00 'Text'", "values apply only to integer types, not VISIBLE_STRING");
}

#[test]
fn min_max_on_string() {
    expect("min_max_on_string", "object 0x2016:00 'Text'", "min/max apply only to integer types, not VISIBLE_STRING");
}

#[test]
fn values_with_min_max() {
    expect("values_with_min_max", "object 0x2017:00 'Option'", "values and min/max exclude each other");
}

#[test]
fn default_wrong_kind() {
    expect("default_wrong_kind", "object 0x2018:00 'Number'", "default \"ten\" must be an integer for UNSIGNED16");
}

#[test]
fn nodeid_on_string() {
    expect(
        "nodeid_on_string",
        "object 0x2019:00 'Text'",
        "a $NODEID default needs an integer type, not VISIBLE_STRING",
    );
}

#[test]
fn nodeid_out_of_range() {
    expect(
        "nodeid_out_of_range",
        "object 0x201A:00 'Small id'",
        "default $NODEID+0xFF (node-ID 1) is outside the UNSIGNED8 range",
    );
}

#[test]
fn pdo_on_string() {
    expect("pdo_on_string", "object 0x201B:00 'Text'", "VISIBLE_STRING cannot be PDO-mapped (pdo = \"tx\")");
}

#[test]
fn persistent_on_ro() {
    expect("persistent_on_ro", "object 0x201C:00 'Actual'", "persistent on a ro entry");
}

#[test]
fn persistent_on_application() {
    expect("persistent_on_application", "object 0x201D:00 'Served'", "persistent on application storage");
}

#[test]
fn const_with_ram_storage() {
    expect("const_with_ram_storage", "object 0x201E:00 'Fixed'", "access const needs storage const, not ram");
}

#[test]
fn const_storage_writable() {
    expect("const_storage_writable", "object 0x201F:00 'Fixed'", "storage const cannot hold a writable (rw) entry");
}

#[test]
fn const_without_default() {
    expect("const_without_default", "object 0x2020:00 'Fixed'", "storage const needs a default");
}

#[test]
fn string_default_too_long() {
    expect("string_default_too_long", "object 0x2021:00 'Name'", "default is 8 bytes, longer than length 4");
}

#[test]
fn string_without_length() {
    expect("string_without_length", "object 0x2022:00 'Name'", "VISIBLE_STRING needs `length`");
}

#[test]
fn length_on_integer() {
    expect(
        "length_on_integer",
        "object 0x2023:00 'Number'",
        "length applies only to VISIBLE_STRING, OCTET_STRING and DOMAIN",
    );
}

#[test]
fn domain_in_ram_without_length() {
    expect("domain_in_ram_without_length", "object 0x2024:00 'Blob'", "DOMAIN in ram storage needs `length`");
}

#[test]
fn handle_on_const() {
    expect("handle_on_const", "object 0x2025:00 'Fixed'", "handle 'fixed' needs storage ram, not const");
}

#[test]
fn handle_on_string() {
    expect("handle_on_string", "object 0x2026:00 'Name'", "handle 'name' needs a fixed-size type, not VISIBLE_STRING");
}

#[test]
fn duplicate_handle() {
    expect("duplicate_handle", "object 0x2028:00 'Second'", "handle 'speed' is also used by object 0x2027:00 'First'");
}

#[test]
fn handle_not_snake_case() {
    expect("handle_not_snake_case", "object 0x2029:00 'Camel'", "handle 'TargetSpeed' is not a snake_case identifier");
}

#[test]
fn repeat_past_255() {
    expect("repeat_past_255", "object 0x202A:FA 'E{n}'", "repeat 10 from sub 250 runs past sub 255");
}

#[test]
fn repeat_default_list_length() {
    expect("repeat_default_list_length", "object 0x202B:01 'E{n}'", "default lists 2 values but repeat is 3");
}

#[test]
fn list_default_without_repeat() {
    expect("list_default_without_repeat", "object 0x202C:01 'E'", "a list default needs `repeat`");
}

#[test]
fn device_type_mismatch() {
    expect(
        "device_type_mismatch",
        "object 0x1000:00 'Device type'",
        "default 0x00020191 differs from [device] device_type 0x00020192",
    );
}

#[test]
fn device_name_mismatch() {
    expect(
        "device_name_mismatch",
        "object 0x1008:00 'Manufacturer device name'",
        "default 'OTHER' differs from [device] device_name 'FIX-1'",
    );
}

#[test]
fn hardware_version_mismatch() {
    expect(
        "hardware_version_mismatch",
        "object 0x1009:00 'Manufacturer hardware version'",
        "default 'HW 2' differs from [device] hardware_version 'HW 1'",
    );
}

#[test]
fn software_version_mismatch() {
    expect(
        "software_version_mismatch",
        "object 0x100A:00 'Manufacturer software version'",
        "default 'SW 2' differs from [device] software_version 'SW 1'",
    );
}

#[test]
fn identity_mismatch() {
    expect(
        "identity_mismatch",
        "object 0x1018:02 'Product code'",
        "default 0x00010002 differs from [device] product_code 0x00010001",
    );
}

#[test]
fn mapping_missing_entry() {
    expect("mapping_missing_entry", "object 0x1600:01 'Mapped object 1'", "maps 0x6042:00, which is not declared");
}

#[test]
fn mapping_not_mappable() {
    expect(
        "mapping_not_mappable",
        "object 0x1600:01 'Mapped object 1'",
        "maps 0x6042:00 'Not mappable', which is not PDO-mappable (pdo = \"no\")",
    );
}

#[test]
fn mapping_wrong_direction() {
    expect(
        "mapping_wrong_direction",
        "object 0x1600:01 'Mapped object 1'",
        "maps 0x6041:00 'Statusword' into a receive PDO, but its pdo is \"tx\"",
    );
}

#[test]
fn mapping_wrong_bit_length() {
    expect(
        "mapping_wrong_bit_length",
        "object 0x1600:01 'Mapped object 1'",
        "maps 0x6040:00 'Controlword' with 8 bits, but UNSIGNED16 takes 16",
    );
}

#[test]
fn mapping_count_past_declared() {
    expect(
        "mapping_count_past_declared",
        "object 0x1600 'Receive PDO 1 mapping'",
        "sub 0 default counts 2 mapped objects but sub 2 is not declared",
    );
}

#[test]
fn mapping_too_long_ethercat() {
    expect(
        "mapping_too_long_ethercat",
        "object 0x1601 'Receive PDO 2 mapping'",
        "default mapping is 48 bytes, longer than max_pdo_bytes_ethercat (40) and max_pdo_bytes_canopen (8)",
    );
}

#[test]
fn mapping_too_long_canopen() {
    expect(
        "mapping_too_long_canopen",
        "object 0x1601 'Receive PDO 2 mapping'",
        "default mapping is 16 bytes, longer than max_pdo_bytes_canopen (8)",
    );
}

#[test]
fn assignment_missing_mapping() {
    expect(
        "assignment_missing_mapping",
        "object 0x1C12:02 'Assigned RxPDO 2'",
        "assigns 0x1601, which is not declared",
    );
}

#[test]
fn assignment_wrong_direction() {
    expect(
        "assignment_wrong_direction",
        "object 0x1C12:01 'Assigned RxPDO 1'",
        "assigns 0x1A00, which is not a receive PDO mapping object (0x1600..0x17FF)",
    );
}

#[test]
fn index_zero() {
    expect("index_zero", "object 0x0000 'Nothing'", "index 0x0000 is not a valid object index");
}

#[test]
fn index_in_data_type_area() {
    expect(
        "index_in_data_type_area",
        "object 0x0007 'Unsigned32 type'",
        "index lies in the data-type area 0x0001..0x0FFF",
    );
}

#[test]
fn missing_description() {
    expect("missing_description", "object 0x2040 'Undescribed'", "missing description");
}

#[test]
fn missing_source() {
    expect("missing_source", "object 0x2041 'Unsourced'", "missing source");
}

#[test]
fn missing_type() {
    expect("missing_type", "object 0x2042:00 'Typeless'", "missing type");
}

#[test]
fn missing_device() {
    expect("missing_device", "[device]", "missing [device] table");
}

#[test]
fn device_field_out_of_range() {
    expect("device_field_out_of_range", "[device]", "node_id 200 is outside 1..=127");
}

#[test]
fn toml_syntax_error() {
    let lines = report("toml_syntax_error");
    assert!(lines[0].starts_with(&format!("{}: TOML parse error", path_of("toml_syntax_error"))), "{lines:#?}");
}

#[test]
fn every_mistake_is_reported() {
    let lines = report("every_mistake_reported");
    let path = path_of("every_mistake_reported");
    let expected = [
        format!("{path}: object 0x2050:00 'First': unknown type 'UINT8'"),
        format!("{path}: object 0x2051:00 'Second': default 70000 is outside the UNSIGNED16 range 0..=65535"),
        format!("{path}: object 0x2052 'Third': missing source"),
        format!("{path}: object 0x2053 'Fourth': missing sub 0 (an ARRAY or RECORD must declare it)"),
    ];
    assert_eq!(lines, expected);
}

#[test]
fn every_error_fixture_has_a_test() {
    let source = include_str!("validate.rs");
    for entry in fs::read_dir(fixtures().join("errors")).expect("errors dir") {
        let name = entry.expect("entry").path().file_stem().expect("stem").to_string_lossy().into_owned();
        assert!(source.contains(&format!("\"{name}\"")), "fixture {name}.toml has no test");
    }
}

#[test]
fn repeat_handle_without_n() {
    expect(
        "repeat_handle_without_n",
        "object 0x202B:02 'Input 2'",
        "handle 'input' is also used by object 0x202B:01 'Input 1'",
    );
}
