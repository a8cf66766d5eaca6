#![no_main]
//! Fuzzes the ply decoder: any bytes must give Ok or a FormatError, never a
//! panic, hang or oversized allocation.
use knitvox::io::{decode, Format, NoResources, ReadOptions};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let opts = ReadOptions { max_points: 1 << 20, ..ReadOptions::default() };
    let _ = decode(Format::Ply, data, &opts, &NoResources);
});
