//! Every fault the simulator injects, shown arriving at the host side of its link, where a
//! gateway would see it.

mod common;

use std::time::Duration;

use common::*;
use flowgate_protocol::codec::StreamError;
use flowgate_protocol::motor::{BoardState, FaultBits, MotorMessage, NmtCommand, NodeId, Target};
use flowgate_protocol::psd::{self, FaultCode, LedSlot, Message, NackReason, Packet, SampleFlags, Schedule};
use flowgate_sim::faults::FaultPlan;
use flowgate_sim::rig::{RigConfig, RigHandle};

async fn rig_with(faults: FaultPlan) -> RigHandle {
    let mut config = RigConfig::new(scenario("e1-standing-obstacle.toml"));
    config.faults = faults;
    rig(config).await
}

fn plan(settings: &[&str]) -> FaultPlan {
    FaultPlan::default().with_settings(&settings.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap()
}

/// Open the PSD line, schedule LEDs 1-3 at 1 ms each, start streaming.
async fn streaming(rig: &RigHandle) -> Host {
    let mut host = Host::open(&rig.psd_path).await;
    let slots = [1, 2, 3].map(|led| LedSlot { led, slot_us: 1000 });
    let s = Schedule::new(&slots, 0, 1).unwrap();
    assert!(matches!(host.request_retry(Message::SetSchedule(s)).await, Message::Ack { .. }));
    assert!(matches!(host.request_retry(Message::StartStream).await, Message::Ack { .. }));
    host
}

/// Everything the host receives for `window`.
async fn receive(host: &mut Host, window: Duration) -> Vec<Arrival> {
    let end = tokio::time::Instant::now() + window;
    let mut out = Vec::new();
    while let Ok(Some(Ok(item))) = tokio::time::timeout_at(end, futures_util::StreamExt::next(&mut host.link)).await {
        out.push((tokio::time::Instant::now(), item));
    }
    out
}

fn sample_seq_gaps(items: &[Arrival]) -> usize {
    let seqs: Vec<u16> = items.iter().filter_map(|(_, i)| i.as_ref().ok()).map(|p| p.seq).collect();
    seqs.windows(2).filter(|w| w[1] != w[0].wrapping_add(1)).count()
}

#[tokio::test]
async fn serial_byte_drops_arrive_as_bad_frames_and_seq_gaps() {
    let rig = rig_with(plan(&["serial_drop=0.003", "seed=3"])).await;
    let mut host = streaming(&rig).await;
    let items = receive(&mut host, Duration::from_millis(600)).await;
    let bad = items.iter().filter(|(_, i)| i.is_err()).count();
    assert!(bad > 0, "no bad frames out of {}", items.len());
    assert!(sample_seq_gaps(&items) > 0);
    assert!(host.link.codec().stats().bad_frames > 0);
    assert!(rig.stats.serial_bytes_dropped.load(std::sync::atomic::Ordering::Relaxed) > 0);
    rig.stop().await;
}

#[tokio::test]
async fn serial_corruption_arrives_as_crc_errors() {
    let rig = rig_with(plan(&["serial_corrupt=0.002", "seed=5"])).await;
    let mut host = streaming(&rig).await;
    let items = receive(&mut host, Duration::from_millis(600)).await;
    let crc = items
        .iter()
        .filter(|(_, i)| {
            matches!(i, Err(StreamError::Frame { error: psd::Error::Crc { .. } | psd::Error::Cobs(_), .. }))
        })
        .count();
    assert!(crc > 0, "no CRC/COBS errors among {} frames", items.len());
    rig.stop().await;
}

#[tokio::test]
async fn a_garbage_burst_arrives_as_one_overlong_run_and_the_stream_recovers() {
    let rig = rig_with(plan(&["serial_burst_at=[0.4]", "serial_burst_len=300"])).await;
    let mut host = streaming(&rig).await;
    let items = receive(&mut host, Duration::from_millis(800)).await;
    let burst = items.iter().position(|(_, i)| {
        matches!(i, Err(StreamError::Overlong { .. })) || matches!(i, Err(StreamError::Frame { .. }))
    });
    let at = burst.expect("the burst shows as a bad frame");
    assert!(
        items[at + 1..].iter().filter(|(_, i)| matches!(i, Ok(Packet { message: Message::Sample(_), .. }))).count()
            > 10,
        "samples resume after the burst"
    );
    rig.stop().await;
}

#[tokio::test]
async fn sample_delay_and_jitter_arrive_as_late_scattered_samples() {
    let rig = rig_with(plan(&["sample_delay_ms=40", "sample_jitter_ms=10"])).await;
    let mut host = streaming(&rig).await;
    // Map the controller clock to host time with a ping (answered at once, not delayed).
    let sent = tokio::time::Instant::now();
    let pong = host.request(Message::Ping { nonce: 1 }).await;
    let rtt = sent.elapsed();
    let Message::Pong { t_ctrl_us, .. } = pong else { panic!("{pong:?}") };
    let host_at_pong = sent + rtt / 2;
    let items = receive(&mut host, Duration::from_millis(500)).await;
    let lateness: Vec<f64> = items
        .iter()
        .filter_map(|(at, i)| match i {
            Ok(Packet { message: Message::Sample(s), .. }) if s.t_ctrl_us > t_ctrl_us => {
                let expected = host_at_pong + Duration::from_micros(s.t_ctrl_us - t_ctrl_us);
                // Signed: arrival minus the sample's stamp on the host clock, ms.
                let late = at.saturating_duration_since(expected).as_secs_f64();
                let early = expected.saturating_duration_since(*at).as_secs_f64();
                Some((late - early) * 1e3)
            }
            _ => None,
        })
        .collect();
    assert!(lateness.len() > 50);
    let mean = lateness.iter().sum::<f64>() / lateness.len() as f64;
    let (lo, hi) = lateness.iter().fold((f64::MAX, f64::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    eprintln!("sample lateness: mean {mean:.1} ms, range {lo:.1}..{hi:.1} ms");
    assert!(mean > 30.0 && mean < 60.0, "mean lateness {mean} ms for a 40 ms delay");
    rig.stop().await;
}

#[tokio::test]
async fn an_occluded_led_arrives_as_weak_signal() {
    let rig = rig_with(plan(&["occlusions=[[2, 0.0, 100.0]]"])).await;
    let mut host = streaming(&rig).await;
    let items = receive(&mut host, Duration::from_millis(300)).await;
    let samples: Vec<psd::Sample> = items
        .iter()
        .filter_map(|(_, i)| match i {
            Ok(Packet { message: Message::Sample(s), .. }) => Some(*s),
            _ => None,
        })
        .collect();
    assert!(samples.iter().filter(|s| s.led == 2).all(|s| s.flags.contains(SampleFlags::WEAK_SIGNAL)));
    assert!(samples.iter().filter(|s| s.led != 2).all(|s| s.flags.is_usable()));
    assert!(samples.iter().any(|s| s.led == 2) && samples.iter().any(|s| s.led == 1));
    rig.stop().await;
}

#[tokio::test]
async fn a_controller_reset_arrives_as_a_reset_fault_and_a_lost_schedule() {
    let rig = rig_with(plan(&["controller_reset_at=0.5"])).await;
    let mut host = streaming(&rig).await;
    host.until(|m| matches!(m, Message::Sample(_))).await;
    host.until(|m| matches!(m, Message::Fault { code: FaultCode::Reset, .. })).await;
    assert!(matches!(
        host.request(Message::StartStream).await,
        Message::Nack { reason: NackReason::NotConfigured, .. }
    ));
    rig.stop().await;
}

async fn enabled_board(rig: &RigHandle) -> CanHost {
    let mut can = CanHost::open(rig.can_path.as_ref().unwrap()).await;
    let node = NodeId::new(1).unwrap();
    can.until(|m| matches!(m, MotorMessage::Heartbeat { .. })).await;
    can.send(MotorMessage::Config { node, accel: 20_000, max_rate: 8_000, timeout_ms: 1000 }).await;
    can.send(MotorMessage::Nmt { target: Target::Node(node), command: NmtCommand::Enable }).await;
    can.until(|m| matches!(m, MotorMessage::Status { state: BoardState::Enabled, .. })).await;
    can
}

#[tokio::test]
async fn can_frame_loss_arrives_as_missing_frames() {
    let rig = rig_with(plan(&["can_loss=0.3", "seed=9"])).await;
    let mut can = CanHost::open(rig.can_path.as_ref().unwrap()).await;
    let got = can.collect(Duration::from_millis(1000)).await;
    // Per second the board sends 10 heartbeats and 20 each of status, rates and position.
    let statuses = got.iter().filter(|(_, m)| matches!(m, MotorMessage::Status { .. })).count();
    eprintln!("with 30% loss: {} frames, {statuses} status frames in 1 s", got.len());
    assert!(statuses < 18, "{statuses} of ~20 status frames arrived");
    assert!(rig.stats.can_frames_lost.load(std::sync::atomic::Ordering::Relaxed) > 10);
    rig.stop().await;
}

#[tokio::test]
async fn a_heartbeat_stop_arrives_as_silence_on_the_heartbeat_id() {
    let started = tokio::time::Instant::now();
    let rig = rig_with(plan(&["heartbeat_stop_at=0.6"])).await;
    let mut can = CanHost::open(rig.can_path.as_ref().unwrap()).await;
    let got = can.collect(Duration::from_millis(1400)).await;
    let since = |at: tokio::time::Instant| at.duration_since(started);
    let heartbeats: Vec<Duration> =
        got.iter().filter(|(_, m)| matches!(m, MotorMessage::Heartbeat { .. })).map(|(at, _)| since(*at)).collect();
    assert!(heartbeats.iter().any(|d| *d < Duration::from_millis(500)), "heartbeats before the stop: {heartbeats:?}");
    assert!(heartbeats.iter().all(|d| *d < Duration::from_millis(750)), "heartbeats after the stop: {heartbeats:?}");
    let late_status = got
        .iter()
        .filter(|(at, m)| matches!(m, MotorMessage::Status { .. }) && since(*at) > Duration::from_millis(900));
    assert!(late_status.count() > 5, "status frames keep coming");
    rig.stop().await;
}

#[tokio::test]
async fn a_board_fault_arrives_as_an_emergency_and_a_fault_state() {
    let rig = rig_with(plan(&["board_fault_at=0.8"])).await;
    let mut can = enabled_board(&rig).await;
    let emcy = can.until(|m| matches!(m, MotorMessage::Emergency { .. })).await;
    assert!(matches!(emcy, MotorMessage::Emergency { faults, .. } if faults.contains(FaultBits::DRIVER)));
    can.until(|m| matches!(m, MotorMessage::Status { state: BoardState::Fault, .. })).await;
    rig.stop().await;
}

#[tokio::test]
async fn bus_off_arrives_as_silence_then_a_bus_fault() {
    let rig = rig_with(plan(&["bus_off_at=0.8", "bus_off_s=0.4"])).await;
    let mut can = enabled_board(&rig).await;
    // Keep the board commanded so the only reason to stop is the bus.
    let node = NodeId::new(1).unwrap();
    let mut seq = 0u8;
    let mut arrivals = Vec::new();
    let end = tokio::time::Instant::now() + Duration::from_millis(1500);
    while tokio::time::Instant::now() < end {
        can.send(MotorMessage::Velocity { node, left: 500, right: 500, seq }).await;
        seq = seq.wrapping_add(1);
        arrivals.extend(can.collect(Duration::from_millis(20)).await);
    }
    // The longest silence is the bus-off window.
    let longest = arrivals.windows(2).map(|w| w[1].0.duration_since(w[0].0)).max().unwrap();
    assert!(longest >= Duration::from_millis(300), "longest gap {longest:?}");
    assert!(arrivals.iter().any(|(_, m)| matches!(m, MotorMessage::Status { state: BoardState::Fault, faults, .. } if faults.contains(FaultBits::BUS))));
    rig.stop().await;
}

/// Faults set in the scenario's `[faults]` table reach the rig as well.
#[tokio::test]
async fn faults_from_the_scenario_file_are_injected() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/e1-standing-obstacle.toml");
    let text = std::fs::read_to_string(&path).unwrap() + "\n[faults]\ncontroller_reset_at = 0.4\n";
    let scenario = flowgate_sim::scenario::SimScenario::from_toml(&text, "e1 + faults").unwrap();
    let rig = rig(RigConfig::new(scenario)).await;
    let mut host = streaming(&rig).await;
    host.until(|m| matches!(m, Message::Fault { code: FaultCode::Reset, .. })).await;
    assert!(matches!(
        host.request(Message::StartStream).await,
        Message::Nack { reason: NackReason::NotConfigured, .. }
    ));
    rig.stop().await;
}
