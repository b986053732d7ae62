//! The recording readers over arbitrary bytes: `flowgate replay` and `record export`
//! (`Recording`) and `record info` (`RecordingInfo`) must end every file with a result or an
//! error, never a panic, an abort or an allocation past their bound (libFuzzer's
//! `-malloc_limit_mb`, 2 GiB by default, catches any single one that a damaged length could
//! ask for). Seeded with real recordings of the demo, whole, cut short and damaged.
#![no_main]
use flowgate::replay::{Recording, RecordingInfo};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(recording) = Recording::from_reader(data, "fuzz") {
        // What the tools print of it.
        let _ = (recording.is_whole(), recording.duration(), recording.config());
    }
    if let Ok(info) = RecordingInfo::scan(|| Ok(data), data.len() as u64, "fuzz") {
        let _ = info.to_string();
    }
});
