//! `protocol/motor.dbc` is generated from the table below and checked here: the committed
//! file must equal what the code says (run with `FLOWGATE_BLESS=1` to rewrite it after a
//! protocol change). A second test has Python cantools decode frames encoded by the Rust
//! code with that DBC and agree on every signal value.

#[path = "../../tests/support/python.rs"]
mod python;

use flowgate_protocol::motor::*;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::Command;

struct Signal {
    name: &'static str,
    start: u32,
    len: u32,
    signed: bool,
    unit: &'static str,
    values: &'static [(u8, &'static str)],
}

const fn sig(name: &'static str, start: u32, len: u32, signed: bool, unit: &'static str) -> Signal {
    Signal { name, start, len, signed, unit, values: &[] }
}

const STATE_VALUES: &[(u8, &str)] = &[(0, "BootUp"), (1, "Disabled"), (2, "Enabled"), (3, "Fault"), (4, "EStop")];
const GW_STATE_VALUES: &[(u8, &str)] =
    &[(1, "Idle"), (2, "Armed"), (3, "Running"), (4, "Stopping"), (5, "Stopped"), (6, "Fault")];
const REASONS: &[(u8, &str)] =
    &[(0, "Unspecified"), (1, "Operator"), (2, "GatewayFault"), (3, "Shutdown"), (4, "External")];
const NMT_VALUES: &[(u8, &str)] = &[(1, "Enable"), (2, "Disable"), (0x81, "Reset"), (0x82, "FaultReset")];

fn fault_bits(base: u32) -> [Signal; 7] {
    [
        sig("fault_cmd_timeout", base, 1, false, ""),
        sig("fault_estop", base + 1, 1, false, ""),
        sig("fault_rate_limit", base + 2, 1, false, ""),
        sig("fault_bus", base + 3, 1, false, ""),
        sig("fault_driver", base + 4, 1, false, ""),
        sig("fault_gateway_lost", base + 5, 1, false, ""),
        sig("fault_estop_input", base + 6, 1, false, ""),
    ]
}

/// One message kind: (name prefix, function code, DLC, sent by the gateway, comment, signals).
type Layout = (&'static str, u16, u8, bool, &'static str, Vec<Signal>);

fn layouts() -> Vec<Layout> {
    let rate = |name| sig(name, 0, 24, true, "pulse/s");
    vec![
        (
            "ESTOP",
            function::ESTOP,
            1,
            true,
            "Emergency stop: any frame on this id stops the axes at once; reason optional",
            vec![Signal { values: REASONS, ..sig("reason", 0, 8, false, "") }],
        ),
        (
            "NMT",
            function::NMT,
            1,
            true,
            "Enable, disable, reset, fault reset",
            vec![Signal { values: NMT_VALUES, ..sig("command", 0, 8, false, "") }],
        ),
        (
            "EMCY",
            function::EMERGENCY,
            1,
            false,
            "Sent once when the board enters Fault: the fault bits",
            fault_bits(0).into(),
        ),
        (
            "VELOCITY",
            function::VELOCITY,
            7,
            true,
            "Both axes' pulse rates; seq increments by one per command",
            vec![rate("left"), Signal { start: 24, ..rate("right") }, sig("seq", 48, 8, false, "")],
        ),
        (
            "CONFIG",
            function::CONFIG,
            8,
            true,
            "Ramp, rate limit and command timeout for both axes",
            vec![
                sig("accel", 0, 24, false, "pulse/s^2"),
                sig("max_rate", 24, 24, false, "pulse/s"),
                sig("timeout_ms", 48, 16, false, "ms"),
            ],
        ),
        ("STATUS", function::STATUS, 4, false, "Board state, fault bits, last applied command seq, seq errors", {
            let mut v = vec![Signal { values: STATE_VALUES, ..sig("state", 0, 8, false, "") }];
            v.extend(fault_bits(8));
            v.push(sig("last_seq", 16, 8, false, ""));
            v.push(sig("seq_errors", 24, 8, false, ""));
            v
        }),
        (
            "AXIS_RATES",
            function::AXIS_RATES,
            6,
            false,
            "Actual pulse rates after the ramp",
            vec![rate("left"), Signal { start: 24, ..rate("right") }],
        ),
        (
            "POSITION",
            function::POSITION,
            8,
            false,
            "Pulse position counters",
            vec![sig("left", 0, 32, true, "pulse"), sig("right", 32, 32, true, "pulse")],
        ),
        (
            "HEARTBEAT",
            function::HEARTBEAT,
            1,
            false,
            "Board heartbeat; state 0 (BootUp) is the boot-up message",
            vec![Signal { values: STATE_VALUES, ..sig("state", 0, 8, false, "") }],
        ),
    ]
}

fn message_name(prefix: &str, node: u8) -> String {
    match (prefix, node) {
        ("HEARTBEAT", 0) => "GW_HEARTBEAT".into(),
        (_, 0) => format!("{prefix}_ALL"),
        _ => format!("{prefix}_N{node}"),
    }
}

fn render_dbc() -> String {
    let mut out = String::new();
    let boards: Vec<String> = (1..=15).map(|n| format!("BOARD{n}")).collect();
    writeln!(
        out,
        "VERSION \"flowgate-motor 1\"\n\nNS_ :\n\tCM_\n\tVAL_\n\nBS_:\n\nBU_: GATEWAY {}\n",
        boards.join(" ")
    )
    .unwrap();
    let mut comments = String::new();
    let mut values = String::new();
    for (prefix, func, dlc, from_gateway, comment, signals) in layouts() {
        let nodes: Vec<u8> = match prefix {
            "ESTOP" | "NMT" | "HEARTBEAT" => (0..=15).collect(),
            _ => (1..=15).collect(),
        };
        for node in nodes {
            let id = u32::from(func << 4 | u16::from(node));
            let board = if node == 0 { "Vector__XXX".to_string() } else { format!("BOARD{node}") };
            let (sender, receiver) = match (prefix, node, from_gateway) {
                ("HEARTBEAT", 0, _) => ("GATEWAY".to_string(), boards.join(",")),
                (_, 0, true) => ("GATEWAY".to_string(), boards.join(",")),
                (_, _, true) => ("GATEWAY".to_string(), board),
                (_, _, false) => (board, "GATEWAY".to_string()),
            };
            let name = message_name(prefix, node);
            writeln!(out, "BO_ {id} {name}: {dlc} {sender}").unwrap();
            let (signals, comment): (&[Signal], &str) = if prefix == "HEARTBEAT" && node == 0 {
                (
                    &[Signal { values: GW_STATE_VALUES, ..sig("state", 0, 8, false, "") }],
                    "Gateway heartbeat: its safety state",
                )
            } else {
                (&signals, comment)
            };
            for s in signals {
                let (min, max) = match (s.signed, s.len) {
                    // Pulse rates are symmetric: ±(2^23 - 1).
                    (true, 24) => (-((1i64 << 23) - 1), (1i64 << 23) - 1),
                    (true, n) => (-(1i64 << (n - 1)), (1i64 << (n - 1)) - 1),
                    (false, n) => (0, (1i64 << n) - 1),
                };
                let sign = if s.signed { '-' } else { '+' };
                writeln!(
                    out,
                    " SG_ {} : {}|{}@1{sign} (1,0) [{min}|{max}] \"{}\" {receiver}",
                    s.name, s.start, s.len, s.unit
                )
                .unwrap();
                if !s.values.is_empty() {
                    let table: Vec<String> = s.values.iter().map(|(v, n)| format!("{v} \"{n}\"")).collect();
                    writeln!(values, "VAL_ {id} {} {} ;", s.name, table.join(" ")).unwrap();
                }
            }
            writeln!(out).unwrap();
            writeln!(comments, "CM_ BO_ {id} \"{comment}\";").unwrap();
        }
    }
    out + "\n" + &comments + "\n" + &values
}

fn manifest_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn motor_dbc_matches_the_code() {
    let path = manifest_dir().join("motor.dbc");
    let want = render_dbc();
    if std::env::var_os("FLOWGATE_BLESS").is_some() {
        std::fs::write(&path, &want).unwrap();
    }
    let have = std::fs::read_to_string(&path).expect("protocol/motor.dbc is missing; run with FLOWGATE_BLESS=1");
    assert!(have == want, "protocol/motor.dbc is stale: rerun this test with FLOWGATE_BLESS=1 and commit the file");
}

/// The DBC signal values of a message, as cantools should read them.
fn signals(m: &MotorMessage) -> Vec<(&'static str, i64)> {
    let bits = |f: FaultBits| -> Vec<(&'static str, i64)> {
        [
            "fault_cmd_timeout",
            "fault_estop",
            "fault_rate_limit",
            "fault_bus",
            "fault_driver",
            "fault_gateway_lost",
            "fault_estop_input",
        ]
        .iter()
        .enumerate()
        .map(|(i, n)| (*n, i64::from(f.0 >> i & 1)))
        .collect()
    };
    match *m {
        MotorMessage::EStop { reason, .. } => vec![("reason", reason as i64)],
        MotorMessage::Nmt { command, .. } => vec![("command", command as i64)],
        MotorMessage::Emergency { faults, .. } => bits(faults),
        MotorMessage::Velocity { left, right, seq, .. } => {
            vec![("left", left.into()), ("right", right.into()), ("seq", seq.into())]
        }
        MotorMessage::Config { accel, max_rate, timeout_ms, .. } => {
            vec![("accel", accel.into()), ("max_rate", max_rate.into()), ("timeout_ms", timeout_ms.into())]
        }
        MotorMessage::Status { state, faults, last_seq, seq_errors, .. } => {
            let mut v = vec![("state", state as i64), ("last_seq", last_seq.into()), ("seq_errors", seq_errors.into())];
            v.extend(bits(faults));
            v
        }
        MotorMessage::AxisRates { left, right, .. } | MotorMessage::Position { left, right, .. } => {
            vec![("left", left.into()), ("right", right.into())]
        }
        MotorMessage::GatewayHeartbeat { state } => vec![("state", state as i64)],
        MotorMessage::Heartbeat { state, .. } => vec![("state", state as i64)],
    }
}

/// A deterministic spread of messages: every kind, every node, extremes and pseudo-random values.
fn sample_messages() -> Vec<MotorMessage> {
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let mut out = Vec::new();
    for n in 1..=15u8 {
        let node = NodeId::new(n).unwrap();
        let r = &mut next;
        let rate = |v: u64| (v % (2 * MAX_PULSE_RATE as u64 + 1)) as i32 - MAX_PULSE_RATE;
        let faults = FaultBits((r() & 0x3F) as u8);
        out.extend([
            MotorMessage::EStop { target: Target::Node(node), reason: EStopReason::from_u8((r() % 5) as u8).unwrap() },
            MotorMessage::Nmt { target: Target::Node(node), command: NmtCommand::FaultReset },
            MotorMessage::Emergency { node, faults },
            MotorMessage::Velocity { node, left: rate(r()), right: rate(r()), seq: r() as u8 },
            MotorMessage::Velocity { node, left: -MAX_PULSE_RATE, right: MAX_PULSE_RATE, seq: 255 },
            MotorMessage::Config {
                node,
                accel: (r() as u32) & MAX_U24,
                max_rate: MAX_U24,
                timeout_ms: (r() as u16).max(1),
            },
            MotorMessage::Status {
                node,
                state: BoardState::from_u8((r() % 5) as u8).unwrap(),
                faults,
                last_seq: r() as u8,
                seq_errors: r() as u8,
            },
            MotorMessage::AxisRates { node, left: rate(r()), right: rate(r()) },
            MotorMessage::Position { node, left: r() as i32, right: i32::MIN },
            MotorMessage::Heartbeat { node, state: BoardState::from_u8((r() % 5) as u8).unwrap() },
        ]);
    }
    out.push(MotorMessage::EStop { target: Target::All, reason: EStopReason::Operator });
    out.push(MotorMessage::Nmt { target: Target::All, command: NmtCommand::Enable });
    out.push(MotorMessage::GatewayHeartbeat { state: GatewayState::Running });
    out
}

#[test]
fn cantools_decodes_rust_frames_with_motor_dbc() {
    let mut cases = String::from("[");
    for (i, m) in sample_messages().iter().enumerate() {
        let frame = m.to_frame().unwrap();
        let hex: String = frame.data().iter().map(|b| format!("{b:02x}")).collect();
        let sigs: Vec<String> = signals(m).iter().map(|(k, v)| format!("\"{k}\": {v}")).collect();
        if i > 0 {
            cases.push(',');
        }
        write!(cases, "{{\"id\": {}, \"data\": \"{hex}\", \"signals\": {{{}}}}}", frame.id().raw(), sigs.join(", "))
            .unwrap();
    }
    cases.push(']');
    let dir = std::env::temp_dir().join(format!("flowgate-dbc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases_path = dir.join("cases.json");
    std::fs::write(&cases_path, cases).unwrap();

    let script = python::peer("dbc");
    let out = Command::new(python::python())
        .arg(&script)
        .arg(manifest_dir().join("motor.dbc"))
        .arg(&cases_path)
        .output()
        .expect("could not run python3 (set FLOWGATE_PYTHON, or run the tests with scripts/test)");
    let _ = std::fs::remove_dir_all(&dir);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "cantools check failed (cantools is installed by scripts/test):\n{stdout}\n{stderr}");
    assert!(stdout.contains(&format!("checked {} frames", sample_messages().len())), "{stdout}");
}
