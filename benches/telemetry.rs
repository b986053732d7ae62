//! What the per-cycle statistics cost the loop (criterion): `Timing::add` records one
//! cycle's end-to-end latency, period and six stage durations in HDR histograms allocated
//! up front. Compare with a cycle's own work (`flowgate bench`: tens of microseconds).
//!
//! cargo bench --bench telemetry

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use flowgate::gateway::shell::telemetry::{CycleRecord, Timing};

fn bench(c: &mut Criterion) {
    let mut timing = Timing::default();
    // Durations that vary cycle to cycle, over the buckets a real run touches.
    let records: Vec<CycleRecord> = (0..1024u64)
        .map(|k| CycleRecord {
            decode_ns: 1_000 + 37 * k,
            checks_ns: 800 + 11 * k,
            track_ns: 2_000 + 53 * k,
            plan_ns: 3_000 + 71 * k,
            encode_ns: 200 + 3 * k,
            can_write_ns: 10_000 + 97 * k,
            e2e_ns: 40_000 + 301 * k,
            period_ns: 17_000_000 + 1_009 * k,
            ..CycleRecord::default()
        })
        .collect();
    let mut k = 0;
    c.bench_function("timing_add_one_cycle", |b| {
        b.iter(|| {
            timing.add(black_box(&records[k & 1023]));
            k += 1;
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
