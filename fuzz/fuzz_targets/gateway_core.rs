//! The gateway core driven by arbitrary PSD bytes, CAN events, ticks and operator requests:
//! it must never panic, and it must never command motion outside Running.
//!
//! The input is a little program, one operation after another (see `step`), each handed to
//! the core through its one door, `Core::handle`, as the rig's shell hands it its inputs. PSD frames can
//! come raw or with a correct CRC and COBS framing (so the fuzzer reaches the handshake and
//! the stream, not only the CRC check); CAN frames are any id and payload.
#![no_main]
use flowgate::config::{RigFile, Goal, Rig};
use flowgate::gateway::core::operator::Request;
use flowgate::gateway::core::{Core, Input, NoClock, Output, State};
use flowgate::gateway::core::CanEvent;
use flowgate::time::HostTime;
use flowgate_protocol::motor::MotorMessage;
use flowgate_protocol::{cobs, crc, CanFrame, CanId};
use libfuzzer_sys::fuzz_target;
use std::sync::OnceLock;
use std::time::Duration;

const RIG: &str = include_str!("../../rig.example.toml");

struct Program<'a>(&'a [u8]);

impl<'a> Program<'a> {
    fn byte(&mut self) -> Option<u8> {
        let (&b, rest) = self.0.split_first()?;
        self.0 = rest;
        Some(b)
    }
    fn bytes(&mut self, n: usize) -> &'a [u8] {
        let n = n.min(self.0.len());
        let (head, rest) = self.0.split_at(n);
        self.0 = rest;
        head
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.byte().unwrap_or(0), self.byte().unwrap_or(0)])
    }
}

/// What the core has said so far: the state it announced last.
struct Watch {
    state: State,
}

impl Watch {
    fn drain(&mut self, core: &mut Core<NoClock>) {
        while let Some(out) = core.poll() {
            let frame = match out {
                Output::State { state, .. } => {
                    self.state = state;
                    continue;
                }
                Output::Can(frame) | Output::Command { frame, .. } => frame,
                _ => continue,
            };
            if let Ok(MotorMessage::Velocity { left, right, .. }) = MotorMessage::parse(&frame) {
                assert!(
                    (left, right) == (0, 0) || self.state == State::Running,
                    "motion ({left}, {right}) commanded in {}",
                    self.state
                );
            }
        }
        assert_eq!(self.state, core.state(), "every state change is announced");
    }
}

fn step(core: &mut Core<NoClock>, now: &mut HostTime, input: &mut Program) -> Option<()> {
    let op = input.byte()?;
    match op % 10 {
        0 => {
            let n = usize::from(input.byte()? % 64);
            core.handle(*now, Input::PsdBytes(input.bytes(n)));
        }
        1 | 2 => {
            // A frame with a correct CRC and COBS framing around arbitrary body bytes.
            let n = usize::from(input.byte()? % 48);
            let body = input.bytes(n);
            let mut frame = [0u8; 64];
            frame[..body.len()].copy_from_slice(body);
            frame[body.len()..body.len() + 2].copy_from_slice(&crc::crc16_ibm3740(body).to_le_bytes());
            let mut wire = [0u8; 80];
            let m = cobs::encode(&frame[..body.len() + 2], &mut wire).ok()?;
            wire[m] = 0;
            core.handle(*now, Input::PsdBytes(&wire[..=m]));
        }
        3 => {
            let id = input.u16() & 0x7ff;
            let n = usize::from(input.byte()? % 9);
            let data = input.bytes(n);
            if let Some(Ok(frame)) = CanId::standard(id).map(|id| CanFrame::new(id, data)) {
                core.handle(*now, Input::Can(CanEvent::Frame(frame)));
            }
        }
        4 | 5 => {
            *now = *now + Duration::from_micros(u64::from(input.u16()) * 10);
            core.handle(*now, Input::Tick);
        }
        6 => {
            let request = match input.byte()? % 8 {
                0 => Request::Arm,
                1 => Request::Start,
                2 => Request::Stop,
                3 => Request::EStop,
                4 => Request::Reset,
                5 => Request::Status,
                6 => {
                    let goals = (0..input.byte()? % 4)
                        .map(|_| Goal {
                            position: [f64::from(input.u16() as i16) * 1e-3, f64::from(input.u16() as i16) * 1e-3],
                            tolerance: f64::from(input.byte().unwrap_or(0)) * 1e-3,
                        })
                        .collect();
                    Request::Goal { goals }
                }
                _ => Request::Cancel,
            };
            core.handle(*now, Input::Request(&request));
        }
        7 => {
            let event = match input.byte()? % 5 {
                0 => CanEvent::Garbled,
                1 => CanEvent::TransmitRefused,
                2 => CanEvent::AdapterStatus { bus_off: false, error_passive: true },
                3 => CanEvent::AdapterStatus { bus_off: true, error_passive: false },
                _ => CanEvent::ErrorFrame { bus_off: input.byte()? & 1 == 1 },
            };
            core.handle(*now, Input::Can(event));
        }
        8 => {
            let link = match input.byte()? % 5 {
                0 => Input::PsdLost,
                1 => Input::PsdConnected,
                2 => Input::CanFailed,
                3 => Input::CanReopened,
                _ => Input::Can(CanEvent::InterfaceDown),
            };
            core.handle(*now, link);
        }
        _ => {
            core.handle(*now, Input::Shutdown);
        }
    }
    Some(())
}

/// The example rig, parsed once (parsing it per input would be most of each execution).
fn rig() -> Rig {
    static RIG_ONCE: OnceLock<Rig> = OnceLock::new();
    RIG_ONCE
        .get_or_init(|| {
            let config: RigFile = toml::from_str(RIG).expect("the example parses");
            config.validate().expect("the example is valid")
        })
        .clone()
}

fuzz_target!(|data: &[u8]| {
    let mut core = Core::new(rig(), NoClock);
    let mut input = Program(data);
    if input.byte().is_some_and(|b| b & 1 == 1) {
        core.handle(HostTime::ZERO, Input::ArmAtStart);
    }
    let mut now = HostTime::ZERO;
    let mut watch = Watch { state: core.state() };
    core.handle(now, Input::PsdConnected);
    watch.drain(&mut core);
    while step(&mut core, &mut now, &mut input).is_some() {
        watch.drain(&mut core);
    }
    watch.drain(&mut core);
});
