//! `list [FILTER]`: the dictionary as the EDS describes it, for finding an object's index or name.

use serde_json::json;

use crate::eds::Dictionary;
use crate::project::persistent;
use crate::value::type_name;

/// Prints the entries of `dict` whose address or name contains `filter`.
pub fn list(dict: &Dictionary, filter: Option<&str>, as_json: bool) -> Result<(), String> {
    let needle = filter.map(str::to_ascii_lowercase);
    let entries: Vec<_> = dict
        .entries
        .iter()
        .filter(|e| {
            needle.as_deref().is_none_or(|n| {
                e.full_name().to_ascii_lowercase().contains(n) || e.address().to_ascii_lowercase().contains(n)
            })
        })
        .collect();
    if entries.is_empty() {
        return Err(format!("no entry of the EDS matches `{}`", filter.unwrap_or_default()));
    }
    if as_json {
        let list: Vec<_> = entries
            .iter()
            .map(|e| {
                json!({
                    "index": e.index, "sub": e.sub, "address": e.address(), "name": e.full_name(),
                    "type": type_name(e.data_type), "access": e.access.word(), "default": e.default,
                    "persistent": persistent(dict, e),
                })
            })
            .collect();
        say!("{}", serde_json::to_string_pretty(&list).map_err(|e| e.to_string())?);
    } else {
        for e in entries {
            say!(
                "{} {:<5} {:<14} {}{}{}",
                e.address(),
                e.access.word(),
                type_name(e.data_type),
                e.full_name(),
                e.default.as_deref().map_or(String::new(), |d| format!(" (default {d})")),
                if persistent(dict, e) { " [saved]" } else { "" },
            );
        }
    }
    Ok(())
}
