//! The core driven by hand, byte by byte and in virtual time: no simulator, no I/O.

use flowgate_protocol::psd::{Info, Message, Packet, Sample, SampleFlags, MAX_WIRE_LEN};

use super::operator::{Refusal, Request};
use super::safety::Garbled;
use super::*;
use crate::config::RigFile;
use crate::Point;

const CTRL_EPOCH_US: u64 = 5_000_000; // the controller booted 5 s before us

fn core() -> Core<NoClock> {
    let text = include_str!("../../../rig.example.toml");
    Core::new(RigFile::from_toml(text, "rig").unwrap().rig("rig").unwrap(), NoClock)
}

impl Core<NoClock> {
    /// A read at `now`, decoded whole: its outputs stay queued for the test to drain, and
    /// what it counted is there to ask at once.
    fn read(&mut self, now: HostTime, bytes: &[u8]) {
        self.psd_bytes(now, bytes);
        self.decode_read(false);
    }
}

/// An obstacle LED not seen is absent: the arm proceeds, unless the LED is required.
#[test]
fn a_required_obstacle_led_not_seen_refuses_the_arm_by_name() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    assert_eq!(c.request(ms(1), None, &Request::Arm), Ok(()));
    let text = include_str!("../../../rig.example.toml").replacen(
        "{ led = 4, radius = 0.07 }",
        "{ led = 4, radius = 0.07, required = true }",
        1,
    );
    let mut c = Core::new(RigFile::from_toml(&text, "rig").unwrap().rig("rig").unwrap(), NoClock);
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    let refusal = c.request(ms(1), None, &Request::Arm).unwrap_err();
    assert_eq!(refusal, Refusal::RequiredObstacleUnseen { led: 4, index: 1 });
    assert_eq!(refusal.to_string(), "obstacle LED 4 is required (leds.obstacles[1].required) and has not been seen");
    assert_eq!(c.state(), State::Idle);
}

/// Every byte thrown away is counted: a whole megabyte with no delimiter (and the
/// delimiter that ends it), a garbled frame's bytes with its delimiter.
#[test]
fn every_discarded_byte_is_counted() {
    let mut c = core();
    c.psd_connected(ms(0));
    let mut run = vec![0x55u8; 1 << 20];
    run.push(0);
    for chunk in run.chunks(1024) {
        c.read(ms(1), chunk);
    }
    assert_eq!(c.counters().serial_dropped_bytes, (1 << 20) + 1);
    assert_eq!(c.counters().bad_serial_frames, 1);
    let mut garbled =
        bytes(Message::Heartbeat { t_ctrl_us: 5, state: flowgate_protocol::psd::ControllerState::Streaming });
    let i = garbled.len() - 3;
    garbled[i] ^= if garbled[i] == 0x80 { 0x40 } else { 0x80 };
    c.read(ms(2), &garbled);
    assert_eq!(c.counters().serial_dropped_bytes, (1 << 20) + 1 + garbled.len() as u64);
    assert_eq!(c.counters().bad_serial_frames, 2);
}

/// A SocketCAN interface that goes down is named as such (not bus-off), and its fault
/// cannot be reset until the link is open again.
#[test]
fn an_interface_gone_down_is_named_and_held_until_the_link_reopens() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    c.request(ms(1), None, &Request::Arm).unwrap();
    c.can_event(ms(2), CanEvent::InterfaceDown);
    assert_eq!(c.state(), State::Fault(StopReason::CanInterfaceDown));
    assert_eq!(StopReason::CanInterfaceDown.to_string(), "CAN interface went down");
    assert_eq!(c.request(ms(3), None, &Request::Reset), Err(Refusal::CauseStillPresent(StopReason::CanInterfaceDown)));
    c.can_reopened();
    assert_eq!(c.request(ms(4), None, &Request::Reset), Ok(()));
    assert_eq!(c.state(), State::Idle);
}

fn ms(v: u64) -> HostTime {
    HostTime::from_nanos(v * 1_000_000)
}

/// The controller's answer to GetInfo `request_seq`: the controller the rig expects.
fn info_reply(request_seq: u16) -> Message {
    Message::Info {
        request_seq,
        info: Info { firmware: [1, 0, 0], psd_counts: [4096; 2], max_leds: 16, clock_hz: 1_000_000 },
    }
}

/// The controller's packets, numbered in order as its firmware does.
fn bytes(message: Message) -> Vec<u8> {
    use std::sync::atomic::{AtomicU16, Ordering};
    static SEQ: AtomicU16 = AtomicU16::new(0);
    let mut wire = [0u8; MAX_WIRE_LEN];
    let n = Packet::new(SEQ.fetch_add(1, Ordering::Relaxed), message).encode(&mut wire).unwrap();
    wire[..n].to_vec()
}

/// Answer every request the core has queued, as a controller would, at `now`.
fn answer(core: &mut Core<NoClock>, now: HostTime) -> Vec<Output> {
    answer_with(core, now, |_| 0)
}

/// The same, the `k`th time-sync reply (from 0) put `sync_off(k)` µs off.
fn answer_with(core: &mut Core<NoClock>, now: HostTime, mut sync_off: impl FnMut(u32) -> i64) -> Vec<Output> {
    let mut syncs = 0;
    let mut other = Vec::new();
    while let Some(o) = core.poll() {
        let Output::Psd(p) = o else {
            other.push(o);
            continue;
        };
        let reply = match p.message {
            Message::GetInfo => info_reply(p.seq),
            Message::TimeSync { host_time_us } => Message::TimeSyncReply {
                request_seq: p.seq,
                host_time_us,
                t_ctrl_us: {
                    syncs += 1;
                    (now.as_nanos() / 1000 + CTRL_EPOCH_US).saturating_add_signed(sync_off(syncs - 1))
                },
            },
            Message::StopStream => continue,
            m => Message::Ack { seq: p.seq, msg_type: m.msg_type() as u8 },
        };
        core.read(now, &bytes(reply));
    }
    other
}

/// A frame of the robot's two LEDs at the floor origin, stamped `stamp_us` on the
/// controller's clock.
fn frame(core: &mut Core<NoClock>, now: HostTime, n: u32, stamp_us: u64) {
    let out = frame_bytes(core, n, stamp_us, 0.0);
    core.read(now, &out);
}

/// The packets of frame `n`, the robot `dx` m along the floor's x from the origin.
fn frame_bytes(core: &Core<NoClock>, n: u32, stamp_us: u64, dx: f64) -> Vec<u8> {
    let cal = core.rig().calibration;
    let mut out = Vec::new();
    for (slot, led, x) in [(0u8, 1u8, dx + 0.035), (1, 2, dx - 0.035)] {
        let (rx, ry) = cal.to_raw(Point::new(x, 0.0)).unwrap();
        let s = Sample {
            frame: n,
            slot,
            led,
            t_ctrl_us: stamp_us,
            x: rx.round() as i32,
            y: ry.round() as i32,
            intensity: 3000,
            flags: SampleFlags(0),
        };
        out.extend(bytes(Message::Sample(s)));
    }
    out.extend(bytes(Message::FrameEnd { frame: n, t_ctrl_us: stamp_us, samples: 2 }));
    out
}

/// One read that carried two frames (a host late to read): each cycle's command is drained
/// while the core is in that cycle's state, so its scene is that cycle's, not the next's.
#[test]
fn a_read_of_two_frames_is_drained_a_cycle_at_a_time() {
    let mut c = armed_with_a_sample();
    commands(&mut c);
    let period_us = c.rig().sample_period.as_micros() as u64;
    let mut read = frame_bytes(&c, 1, CTRL_EPOCH_US + 19_000 + period_us, 0.001);
    read.extend(frame_bytes(&c, 2, CTRL_EPOCH_US + 19_000 + 2 * period_us, 0.002));
    c.handle(ms(60), Input::PsdBytes(&read));
    let mut seen = Vec::new();
    while let Some(output) = c.poll() {
        if let Output::Command { record, .. } = output {
            let scene = c.scene(HostTime::from_nanos(record.rx_ns));
            assert_eq!((scene.cycle, scene.pose[0], scene.pose[1]), (record.cycle, record.x, record.y));
            seen.push(record.x);
        }
    }
    assert_eq!(seen.len(), 2, "a command a frame");
    assert!(seen[1] > seen[0], "the second cycle saw the robot further on: {seen:?}");
}

#[test]
fn the_handshake_syncs_the_clock_and_samples_before_it_are_discarded() {
    let mut c = core();
    c.psd_connected(ms(0));
    // A stream already running before the handshake: its stamps mean nothing yet.
    frame(&mut c, ms(1), 0, CTRL_EPOCH_US + 1000);
    assert_eq!(c.counters().samples_unsynced, 3);
    assert_eq!(c.counters().samples, 0);
    let out = answer(&mut c, ms(2));
    assert!(out.contains(&Output::Streaming), "{out:?}");
    let streaming = Notice::Streaming { firmware: Some([1, 0, 0]) };
    assert!(out.iter().any(|o| matches!(o, Output::Notice { notice, .. } if *notice == streaming)), "{out:?}");
    assert!(c.psd.is_streaming());
    // Synced: a frame stamped 1 ms ago is a pose 1 ms old.
    frame(&mut c, ms(10), 1, 9_000 + CTRL_EPOCH_US);
    assert_eq!(c.counters().samples, 2);
    let at = c.vehicles[ROBOT].pose.time().unwrap();
    assert!((at - 0.009).abs() < 1e-6, "{at}");
}

/// Protocol 2: an answer names its request. An Info or a TimeSyncReply that names
/// another seq (a late answer to an earlier try) is not taken; the matching one is.
#[test]
fn replies_naming_another_request_are_not_taken() {
    let mut c = core();
    c.psd_connected(ms(0));
    let mut streaming = false;
    let mut stale_replies = 0;
    for step in 1..20 {
        let now = ms(step);
        let requests: Vec<Packet> = std::iter::from_fn(|| c.poll())
            .filter_map(|o| match o {
                Output::Psd(p) => Some(p),
                Output::Streaming => {
                    streaming = true;
                    None
                }
                _ => None,
            })
            .collect();
        for p in requests {
            let info = Info { firmware: [1, 0, 0], psd_counts: [4096; 2], max_leds: 16, clock_hz: 1_000_000 };
            let (stale, good) = match p.message {
                Message::GetInfo => (
                    Message::Info { request_seq: p.seq.wrapping_sub(1), info },
                    Message::Info { request_seq: p.seq, info },
                ),
                Message::TimeSync { host_time_us } => {
                    let t_ctrl_us = now.as_nanos() / 1000 + CTRL_EPOCH_US;
                    (
                        Message::TimeSyncReply { request_seq: p.seq.wrapping_add(7), host_time_us, t_ctrl_us },
                        Message::TimeSyncReply { request_seq: p.seq, host_time_us, t_ctrl_us },
                    )
                }
                m => {
                    c.read(now, &bytes(Message::Ack { seq: p.seq, msg_type: m.msg_type() as u8 }));
                    continue;
                }
            };
            // The stale answer alone moves nothing on; the true one does.
            // The handshake's step and the clock offset, as the session shows them.
            let phase = |c: &Core<NoClock>| {
                let d = format!("{:?}", c.psd);
                d[d.find("phase:").unwrap()..d.find(", info:").unwrap()].to_string()
            };
            let before = phase(&c);
            c.read(now, &bytes(stale));
            assert_eq!(before, phase(&c), "a reply naming another request was taken");
            stale_replies += 1;
            c.read(now, &bytes(good));
        }
    }
    assert!(streaming && stale_replies == 2, "{stale_replies}");
}

#[test]
fn a_future_stamp_is_discarded_and_does_not_freeze_the_pose() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    frame(&mut c, ms(20), 0, CTRL_EPOCH_US + 19_000);
    // CRC-valid, stamped an hour ahead.
    frame(&mut c, ms(40), 1, CTRL_EPOCH_US + 3_600_000_000);
    assert_eq!(c.counters().samples_from_future, 2);
    frame(&mut c, ms(60), 2, CTRL_EPOCH_US + 59_000);
    let at = c.vehicles[ROBOT].pose.time().unwrap();
    assert!((at - 0.059).abs() < 1e-6, "the true pose is taken: {at}");
}

#[test]
fn a_silent_controller_fails_the_handshake_after_three_tries() {
    let mut c = core();
    c.psd_connected(ms(0));
    let mut failed = None;
    let mut now = ms(0);
    while failed.is_none() && now < ms(5000) {
        now = c.next_deadline();
        c.tick(now);
        while let Some(o) = c.poll() {
            if let Output::SetupFailed(e) = o {
                failed = Some((now, e));
            }
        }
    }
    let (at, e) = failed.expect("gave up");
    assert_eq!(e, SetupError::Silent { request: "GetInfo" });
    assert_eq!(at, ms(1050), "three tries, 350 ms apart");
}

#[test]
fn watchdogs_fire_at_their_deadline() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    c.request(ms(1), None, &Request::Arm).unwrap();
    let expected = ms(1) + c.rig().safety.sample_timeout;
    assert!(c.next_deadline() <= expected);
    let mut now = ms(1);
    while c.state() == State::Armed {
        now = c.next_deadline();
        c.tick(now);
    }
    // The first to expire: the board's heartbeat (never heard) or the samples.
    assert!(matches!(c.state(), State::Fault(StopReason::SamplesStopped | StopReason::HeartbeatLost { .. })));
    assert!(now <= expected, "{now} vs {expected}");
}

/// Garbage where the samples were (noise that never makes a frame): the sample watchdog
/// names the line garbled, with what came since the last sample, not silent.
#[test]
fn garbage_in_place_of_samples_is_named_garbled_not_silent() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    c.request(ms(1), None, &Request::Arm).unwrap();
    // 3,000 bytes of noise without a frame's end, then one that ends a bad frame.
    c.read(ms(20), &[0x55; 3000]);
    c.read(ms(40), &[0]);
    while c.state() == State::Armed {
        let now = c.next_deadline();
        c.tick(now);
    }
    let reason = StopReason::SerialGarbled { frames: 1, bytes: 3001, found: Garbled::NoSample };
    assert_eq!(c.state(), State::Fault(reason));
    assert_eq!(
        reason.to_string(),
        "garbled serial data and no sample through it (1 bad frame, 3001 bytes dropped since the last sample)"
    );
}

fn commands(c: &mut Core<NoClock>) -> usize {
    let mut n = 0;
    while let Some(o) = c.poll() {
        n += usize::from(matches!(o, Output::Command { .. }));
    }
    n
}

/// The same frame twice (same packets, same frame counter, as a line echoing itself):
/// one command, the copy discarded and counted.
#[test]
fn a_duplicated_frame_gives_one_command() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    c.request(ms(1), None, &Request::Arm).unwrap();
    commands(&mut c);
    let wire = frame_bytes(&c, 7, CTRL_EPOCH_US + 19_000, 0.0);
    c.read(ms(20), &wire);
    c.read(ms(20), &wire);
    assert_eq!(commands(&mut c), 1, "one command for one frame");
    // The copy of the block: its last packet repeats the last one seen, the two before
    // it are behind it.
    assert_eq!((c.counters().psd_duplicates, c.counters().psd_out_of_order), (1, 2));
    // The same frame again under new sequence numbers (a replayed frame): still no command.
    c.read(ms(21), &frame_bytes(&c, 7, CTRL_EPOCH_US + 19_000, 0.0));
    assert_eq!(commands(&mut c), 0);
    assert_eq!(c.counters().frames_repeated, 1);
}

/// Samples from an LED or slot outside the schedule are discarded; a sample of another
/// frame is not used for this one; gaps in frames and packets are counted.
#[test]
fn samples_are_checked_against_the_schedule_and_their_frame() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    let stray = |frame: u32, slot: u8, led: u8| {
        Message::Sample(Sample {
            frame,
            slot,
            led,
            t_ctrl_us: CTRL_EPOCH_US + 1_000,
            x: 0,
            y: 0,
            intensity: 3000,
            flags: SampleFlags(0),
        })
    };
    c.read(ms(2), &bytes(stray(0, 0, 9))); // LED 9 is not scheduled
    c.read(ms(2), &bytes(stray(0, 1, 1))); // LED 1 is slot 0, not 1
    assert_eq!(c.counters().samples_unscheduled, 2);
    assert_eq!(c.counters().samples, 0);
    c.read(ms(3), &bytes(stray(4, 0, 1))); // a sample of frame 4 ...
    c.read(ms(3), &bytes(Message::FrameEnd { frame: 5, t_ctrl_us: CTRL_EPOCH_US + 2_000, samples: 2 })); // ... ended as 5
    assert_eq!(c.counters().frames_lost, 1);
    assert_eq!(c.counters().frames_incomplete, 1);
    assert!(c.vehicles[ROBOT].pose.time().is_none(), "no pose from another frame's sample");
    frame(&mut c, ms(40), 9, CTRL_EPOCH_US + 39_000);
    assert_eq!(c.counters().frames_lost, 1 + 3, "frames 6, 7 and 8 never came");
}

/// A controller that cannot run the schedule (here: 2 LEDs for a schedule of 4) is not
/// the configured one: the handshake fails, naming why.
/// A controller that announces its boot before it answers GetInfo: the handshake goes on
/// from the schedule, and the answer, when it comes, is still checked.
#[test]
fn a_boot_announced_before_the_identity_does_not_skip_its_check() {
    let mut c = core();
    c.psd_connected(ms(0));
    let mut asked = None;
    while let Some(o) = c.poll() {
        if let Output::Psd(Packet { seq, message: Message::GetInfo }) = o {
            asked = Some(seq);
        }
    }
    let reset = Message::Fault { code: flowgate_protocol::psd::FaultCode::Reset, detail: 0 };
    c.read(ms(1), &bytes(reset));
    let info = Info { firmware: [1, 0, 0], psd_counts: [4096; 2], max_leds: 2, clock_hz: 1_000_000 };
    c.read(ms(2), &bytes(Message::Info { request_seq: asked.expect("GetInfo sent"), info }));
    let failed = std::iter::from_fn(|| c.poll()).find_map(|o| match o {
        Output::SetupFailed(e) => Some(e),
        _ => None,
    });
    let e = failed.expect("refused");
    assert_eq!(
        e.to_string(),
        "PSD controller drives 2 LEDs (its Info.max_leds); the schedule has 4 ([leds] and [[vehicles]])"
    );
}

#[test]
fn a_controller_of_another_kind_is_refused_at_the_handshake() {
    let mut c = core();
    c.psd_connected(ms(0));
    let mut failed = None;
    while let Some(o) = c.poll() {
        if let Output::Psd(Packet { seq, message: Message::GetInfo }) = o {
            let info = Info { firmware: [1, 0, 0], psd_counts: [4096; 2], max_leds: 2, clock_hz: 1_000_000 };
            c.read(ms(1), &bytes(Message::Info { request_seq: seq, info }));
        }
        if let Output::SetupFailed(e) = o {
            failed = Some(e);
        }
    }
    let e = failed.expect("refused");
    assert_eq!(
        e.to_string(),
        "PSD controller drives 2 LEDs (its Info.max_leds); the schedule has 4 ([leds] and [[vehicles]])"
    );
}

/// Answer the handshake as [`answer`] does, its first time-sync reply `off_us` off (one
/// odd reply); whether the controller streams again.
fn answer_syncs_off(core: &mut Core<NoClock>, now: HostTime, off_us: i64) -> bool {
    answer_with(core, now, |k| if k == 0 { off_us } else { 0 }).contains(&Output::Streaming)
}

/// A handshake after the clock was taken once (an operator's reset, a line that came back)
/// does not take one odd time-sync reply on its word: it asks again, and takes the clock
/// two replies in a row agree on. Without this check, every sample after a reset was 80 ms
/// off (found by the fault swarm).
#[test]
fn a_handshake_takes_no_odd_time_sync_reply_on_its_word() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    let held = c.psd.clock();
    c.psd_connected(ms(500));
    assert!(answer_syncs_off(&mut c, ms(501), 80_000), "streaming again");
    assert!(c.psd.is_streaming());
    let step_ns = c.psd.clock().as_nanos() - held.as_nanos();
    assert!(step_ns.unsigned_abs() < 1_000_000, "the odd reply was taken: {step_ns} ns");
    // Frames stamped on the true clock are poses of their own time, not from the future.
    frame(&mut c, ms(520), 1, CTRL_EPOCH_US + 519_000);
    assert_eq!(c.counters().samples_from_future, 0);
    assert!((c.vehicles[ROBOT].pose.time().unwrap() - 0.519).abs() < 1e-6);
}

/// A pose lost because the frames that carried it were garbled is named for the garbage,
/// with its counts since the last pose, not as a pose lost; an occluded robot (its samples
/// arrive, weak) is still "robot pose lost".
#[test]
fn a_pose_lost_in_garbage_is_named_garbled() {
    let mut c = armed_with_a_sample();
    // The robot's frames garbled from here; the line stays busy (no quiet gap).
    for k in 1..12u32 {
        let mut garbled = bytes(Message::FrameEnd {
            frame: k,
            t_ctrl_us: CTRL_EPOCH_US + 19_000 + u64::from(k) * 20_000,
            samples: 2,
        });
        garbled[3] ^= 0x5A;
        c.read(ms(20 + 20 * u64::from(k)), &garbled);
        c.sampled(ms(20 + 20 * u64::from(k)));
    }
    let reason = c.pose_lost_cause(ROBOT, ms(200));
    assert!(matches!(reason, StopReason::SerialGarbled { frames: 11, found: Garbled::NoPose, .. }), "{reason:?}");
    assert!(
        reason.to_string().starts_with("garbled serial data and no robot pose through it (11 bad frames"),
        "{reason}"
    );
    c.vehicles[ROBOT].pose_watch.seen_weak(true);
    assert_eq!(c.pose_lost_cause(ROBOT, ms(200)), StopReason::PoseLost);
}

/// A packet numbered `seq`, whatever the controller's count.
fn numbered(seq: u16, message: Message) -> Vec<u8> {
    let mut wire = [0u8; MAX_WIRE_LEN];
    let n = Packet::new(seq, message).encode(&mut wire).unwrap();
    wire[..n].to_vec()
}

/// A core streaming, armed at 2 ms, its last sample (a frame of the robot) at 20 ms.
fn armed_with_a_sample() -> Core<NoClock> {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    c.request(ms(2), None, &Request::Arm).unwrap();
    frame(&mut c, ms(20), 0, CTRL_EPOCH_US + 19_000);
    c
}

/// Drive the core to its next fault (or give up at `until`).
fn run_to_fault(c: &mut Core<NoClock>, until: HostTime) -> StopReason {
    while c.state().is_active() && c.next_deadline() <= until {
        let now = c.next_deadline();
        c.tick(now);
    }
    let State::Fault(reason) = c.state() else { panic!("no fault by {until}: {}", c.state()) };
    reason
}

/// A frame begun and never ended (its delimiter lost) on a line that then went quiet is
/// garbage: the sample watchdog names the line garbled, counting it, not the controller
/// silent (a handshake's answer lost so after a reset reads as the line's noise).
#[test]
fn a_frame_cut_short_on_a_quiet_line_is_named_garbled() {
    let mut c = armed_with_a_sample();
    let heartbeat =
        bytes(Message::Heartbeat { t_ctrl_us: 5, state: flowgate_protocol::psd::ControllerState::Streaming });
    let cut = &heartbeat[..heartbeat.len() - 1];
    c.read(ms(30), cut);
    let reason = run_to_fault(&mut c, ms(500));
    let n = cut.len() as u32;
    assert_eq!(reason, StopReason::SerialGarbled { frames: 1, bytes: n, found: Garbled::NoSample });
    // Still waiting in the decoder, not yet dropped: the line's accounts say so.
    assert_eq!(c.serial_bytes().buffered, u64::from(n));
}

/// An arm is no sample: the garbage that came since the last sample still names the stop
/// that follows it (an operator's reset and arm on a noisy line).
#[test]
fn garbage_before_an_arm_names_the_stop_after_it() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    frame(&mut c, ms(20), 0, CTRL_EPOCH_US + 19_000);
    let mut garbled = bytes(Message::FrameEnd { frame: 1, t_ctrl_us: CTRL_EPOCH_US + 39_000, samples: 2 });
    garbled[3] ^= 0x5A;
    c.read(ms(40), &garbled);
    c.request(ms(50), None, &Request::Arm).unwrap();
    let reason = run_to_fault(&mut c, ms(500));
    assert!(matches!(reason, StopReason::SerialGarbled { frames: 1, found: Garbled::NoSample, .. }), "{reason:?}");
}

/// While a handshake waits, its answer discarded for its sequence number (one packet
/// numbered far ahead came first, and the true ones now look old): the stop names the
/// sequence, not the controller silent.
#[test]
fn a_handshake_answer_discarded_for_its_number_names_the_sequence() {
    let mut c = armed_with_a_sample();
    // The line reopened: the handshake again, its window of sequence numbers afresh.
    c.psd_connected(ms(30));
    let mut info_seq = None;
    while let Some(o) = c.poll() {
        if let Output::Psd(Packet { seq, message: Message::GetInfo }) = o {
            info_seq = Some(seq);
        }
    }
    let info = info_reply(info_seq.expect("GetInfo sent"));
    c.read(
        ms(31),
        &numbered(40_000, Message::Heartbeat { t_ctrl_us: 5, state: flowgate_protocol::psd::ControllerState::Idle }),
    );
    c.read(ms(31), &numbered(7, info));
    assert_eq!(c.counters().psd_sequence_discards(), 1);
    let stop = run_to_fault(&mut c, ms(500));
    assert_eq!(stop, StopReason::PsdSequence { handshake: true });
    assert_eq!(
        stop.to_string(),
        "PSD packets discarded for their sequence numbers while the handshake waited for its answer"
    );
    // Cleared without a restart: the operator's reset configures the controller again, and
    // the robot arms again.
    let t = c.next_deadline().max(ms(600));
    c.request(t, None, &Request::Reset).unwrap();
    answer(&mut c, t);
    c.request(t, None, &Request::Arm).unwrap();
    assert_eq!(c.state(), State::Armed);
}

/// A handshake whose time syncs were held (round trips beyond the bound) goes on late for
/// them: a watchdog that fires before its stream starts names the clock, whichever step
/// it waits on by then.
#[test]
fn a_handshake_late_for_held_time_syncs_names_the_clock() {
    let mut c = armed_with_a_sample();
    c.psd_connected(ms(30));
    // Answer each request 20 ms late (the time syncs held), up to the start's.
    let mut now = ms(30);
    'handshake: loop {
        let pending: Vec<Packet> = std::iter::from_fn(|| c.poll())
            .filter_map(|o| if let Output::Psd(p) = o { Some(p) } else { None })
            .collect();
        now = now + std::time::Duration::from_millis(20);
        for p in pending {
            let reply = match p.message {
                Message::GetInfo => info_reply(p.seq),
                Message::TimeSync { host_time_us } => Message::TimeSyncReply {
                    request_seq: p.seq,
                    host_time_us,
                    t_ctrl_us: now.as_nanos() / 1000 + CTRL_EPOCH_US,
                },
                Message::StartStream => break 'handshake,
                Message::StopStream => continue,
                m => Message::Ack { seq: p.seq, msg_type: m.msg_type() as u8 },
            };
            c.read(now, &bytes(reply));
        }
    }
    // Waiting on the start's answer, not on a time sync.
    assert!(c.psd.in_handshake());
    assert_eq!(run_to_fault(&mut c, now + std::time::Duration::from_millis(200)), StopReason::ClockUnsynced);
}

/// The controller's clock stepped back just after a handshake took it: every frame of the
/// new stream looks older than the stream itself, as frames of the old one still in flight
/// would. The line keeps order, so a frame counted after the last one before the restart
/// but stamped before it is the clock: a pose stop then names it. Frames of the old stream
/// still in flight (counted and stamped after it) are not.
#[test]
fn a_clock_stepped_back_after_the_handshake_is_named_the_clock() {
    let mut c = core();
    c.psd_connected(ms(0));
    answer(&mut c, ms(1));
    c.request(ms(2), None, &Request::Arm).unwrap();
    for k in 0..5u32 {
        let t = 20 + 20 * u64::from(k);
        frame(&mut c, ms(t), k, CTRL_EPOCH_US + (t - 1) * 1000);
    }
    // The operator's e-stop and reset: the controller configured again on the same line.
    c.request(ms(105), None, &Request::EStop).unwrap();
    c.request(ms(110), None, &Request::Reset).unwrap();
    answer(&mut c, ms(111));
    // The old stream's last frame, still in flight: no step.
    frame(&mut c, ms(112), 5, CTRL_EPOCH_US + 119_000 - 20_000);
    assert_eq!(c.stamps.stepped(), None);
    // The new stream's, its clock stepped back 461 ms.
    frame(&mut c, ms(131), 6, CTRL_EPOCH_US + 130_000 - 461_000);
    assert_eq!(c.stamps.stepped(), Some(ms(131)));
    assert_eq!(c.pose_lost_cause(ROBOT, ms(140)), StopReason::ClockJumped);
}
