//! Does a flood of operator requests delay the control loop? `cargo bench --bench
//! operator_flood` runs E1 in real time (the simulator and the gateway over ptys) twice:
//! quiet, and with four clients sending `status` over the control socket as fast as the
//! gateway answers. It prints the gateway's cycle latency (serial read to CAN write) for both.

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use flowgate::gateway;

use flowgate::gateway::core::Progress;

use flowgate::gateway::shell::Controls;
use flowgate::lab::Scenario;
use tokio::sync::watch;

const CLIENTS: usize = 4;

async fn once(s: &Scenario, flood: bool) -> (gateway::shell::Report, f64) {
    let handle = flowgate_sim::rig::start(flowgate_sim::rig::RigConfig::new(s.sim.clone())).await.expect("rig");
    let can = format!("slcan:{}?bitrate=1000000", handle.can_path.as_ref().expect("slcan").display());
    let dir = std::env::temp_dir().join(format!("flowgate-flood-{}-{flood}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let socket = dir.join("control.sock");
    let mut cfg = s.rig_file(&handle.psd_path, &can, None);
    cfg.operator.socket = Some(socket.clone());
    let rig = cfg.rig("bench").expect("rig config");
    let (stop_tx, stop_rx) = watch::channel(false);
    let (progress_tx, mut progress) = watch::channel(Progress::default());
    let gw = tokio::spawn(gateway::shell::run(rig, Controls::new(stop_rx, true), Some(progress_tx)));
    let running = Arc::new(AtomicBool::new(true));
    let served = Arc::new(AtomicU64::new(0));
    let started = Instant::now();
    let clients: Vec<_> = (0..if flood { CLIENTS } else { 0 })
        .map(|_| {
            let (socket, running, served) = (socket.clone(), running.clone(), served.clone());
            std::thread::spawn(move || {
                let stream = loop {
                    match UnixStream::connect(&socket) {
                        Ok(s) => break s,
                        Err(_) if running.load(Ordering::Relaxed) => std::thread::sleep(Duration::from_millis(5)),
                        Err(_) => return,
                    }
                };
                let mut reader = BufReader::new(stream.try_clone().expect("clone"));
                let mut writer = stream;
                let mut line = String::new();
                while running.load(Ordering::Relaxed) {
                    if writer.write_all(b"{\"cmd\":\"status\"}\n").is_err() {
                        return;
                    }
                    line.clear();
                    if reader.read_line(&mut line).unwrap_or(0) == 0 {
                        return;
                    }
                    served.fetch_add(1, Ordering::Relaxed);
                }
            })
        })
        .collect();
    let _ =
        tokio::time::timeout(Duration::from_secs_f64(s.time_limit), progress.wait_for(|p| p.state.is_terminal())).await;
    let elapsed = started.elapsed().as_secs_f64();
    let _ = stop_tx.send(true);
    let report = gw.await.expect("join").expect("gateway");
    running.store(false, Ordering::Relaxed);
    for c in clients {
        let _ = c.join();
    }
    handle.stop().await;
    let _ = std::fs::remove_dir_all(&dir);
    (report, served.load(Ordering::Relaxed) as f64 / elapsed)
}

fn main() {
    let s = Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/e1-standing-obstacle.toml"))
        .expect("scenario");
    let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().expect("runtime");
    println!("E1 in real time, the gateway's cycle latency (serial read -> CAN write done), µs:");
    println!("{:<34} {:>7} {:>7} {:>7} {:>8} {:>8} {:>12}", "", "cycles", "p50", "p99", "p99.9", "max", "requests/s");
    for flood in [false, true] {
        let (r, rate) = runtime.block_on(once(&s, flood));
        let name = if flood { format!("{CLIENTS} clients flooding `status`") } else { "quiet".to_string() };
        println!(
            "{name:<34} {:>7} {:>7.0} {:>7.0} {:>8.0} {:>8.0} {:>12.0}   final: {}",
            r.counters.cycles, r.e2e.p50_us, r.e2e.p99_us, r.e2e.p999_us, r.e2e.max_us, rate, r.final_state
        );
    }
}
