//! The core's inputs as a recording's JSON messages, and back.

use super::{CAN_RX, GATEWAY_INPUT, PSD_RX};
use crate::gateway::core::input::CanEvent;
use crate::gateway::core::input::{InputRecord, RecordedInput, PSD_CHUNK};
use crate::time::HostTime;
use flowgate_protocol::{CanFrame, CanId};
use serde_json::{json, Value};

pub(super) fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write as _;
    bytes.iter().fold(String::with_capacity(2 * bytes.len()), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

pub(super) fn unhex(text: &str) -> Option<Vec<u8>> {
    if !text.len().is_multiple_of(2) {
        return None;
    }
    (0..text.len()).step_by(2).map(|i| u8::from_str_radix(text.get(i..i + 2)?, 16).ok()).collect()
}

/// A CAN frame as JSON: id, whether extended or remote, length, data in hex.
pub fn frame_json(frame: &CanFrame) -> Value {
    let (id, extended) = match frame.id() {
        CanId::Standard(id) => (u32::from(id), false),
        CanId::Extended(id) => (id, true),
    };
    json!({
        "id": id,
        "extended": extended,
        "remote": frame.is_remote(),
        "dlc": frame.dlc(),
        "data": hex(frame.data()),
    })
}

/// A frame back from [`frame_json`].
pub fn frame_from_json(v: &Value) -> Option<CanFrame> {
    let id = u32::try_from(v.get("id")?.as_u64()?).ok()?;
    let id = if v.get("extended")?.as_bool()? { CanId::Extended(id) } else { CanId::Standard(u16::try_from(id).ok()?) };
    if v.get("remote")?.as_bool()? {
        CanFrame::remote(id, u8::try_from(v.get("dlc")?.as_u64()?).ok()?).ok()
    } else {
        CanFrame::new(id, &unhex(v.get("data")?.as_str()?)?).ok()
    }
}

/// An input record as JSON (its channel comes from [`input_channel`]). Its sequence number
/// and host time go in the MCAP message header (`sequence`, and `log_time` less the
/// clock's origin), not here: per message they would be a tenth of a compressed recording.
pub fn input_json(r: &InputRecord) -> Value {
    let mut v = json!({ "kind": r.input.as_input().kind() });
    let extra = match &r.input {
        RecordedInput::PsdBytes { len, bytes } => json!({ "bytes": hex(&bytes[..usize::from(*len)]) }),
        RecordedInput::Can(event) => match event {
            CanEvent::Frame(f) => json!({ "event": "frame", "frame": frame_json(f) }),
            CanEvent::ErrorFrame { bus_off } => json!({ "event": "error_frame", "bus_off": bus_off }),
            CanEvent::Garbled => json!({ "event": "garbled" }),
            CanEvent::TransmitRefused => json!({ "event": "transmit_refused" }),
            CanEvent::InterfaceDown => json!({ "event": "interface_down" }),
            CanEvent::AdapterStatus { bus_off, error_passive } => {
                json!({ "event": "adapter_status", "bus_off": bus_off, "error_passive": error_passive })
            }
        },
        RecordedInput::Request(request) => json!({ "request": request }),
        RecordedInput::VehicleRequest { vehicle, request } => json!({ "vehicle": vehicle, "request": request }),
        _ => return v,
    };
    if let (Some(v), Value::Object(extra)) = (v.as_object_mut(), extra) {
        v.extend(extra);
    }
    v
}

/// The channel an input goes on.
pub fn input_channel(input: &RecordedInput) -> &'static str {
    match input {
        RecordedInput::PsdBytes { .. } => PSD_RX,
        RecordedInput::Can(_) => CAN_RX,
        _ => GATEWAY_INPUT,
    }
}

/// An input record back from its JSON and its message header's sequence number and host
/// time; the error says what is wrong with it. A recording that carries `seq` and `t_ns`
/// in the message itself is read by those.
pub fn input_from_json(v: &Value, seq: u64, at: HostTime) -> Result<InputRecord, String> {
    let field = |name: &str| v.get(name).ok_or_else(|| format!("no `{name}`"));
    let seq = match v.get("seq") {
        Some(s) => s.as_u64().ok_or("`seq` is not a count")?,
        None => seq,
    };
    let at = match v.get("t_ns") {
        Some(t) => HostTime::from_nanos(t.as_u64().ok_or("`t_ns` is not a count")?),
        None => at,
    };
    let kind = field("kind")?.as_str().ok_or("`kind` is not text")?;
    let flag = |name: &str| field(name).and_then(|f| f.as_bool().ok_or_else(|| format!("`{name}` is not a boolean")));
    let input = match kind {
        "psd_connected" => RecordedInput::PsdConnected,
        "psd_lost" => RecordedInput::PsdLost,
        "psd_bytes" => {
            let data = unhex(field("bytes")?.as_str().unwrap_or("?")).ok_or("`bytes` is not hex")?;
            if data.len() > PSD_CHUNK {
                return Err(format!("{} bytes in one read: at most {PSD_CHUNK}", data.len()));
            }
            let mut bytes = [0; PSD_CHUNK];
            bytes[..data.len()].copy_from_slice(&data);
            RecordedInput::PsdBytes { len: data.len() as u16, bytes }
        }
        "can" => RecordedInput::Can(match field("event")?.as_str().unwrap_or("?") {
            "frame" => CanEvent::Frame(frame_from_json(field("frame")?).ok_or("`frame` is not a CAN frame")?),
            "error_frame" => CanEvent::ErrorFrame { bus_off: flag("bus_off")? },
            "garbled" => CanEvent::Garbled,
            "transmit_refused" => CanEvent::TransmitRefused,
            "interface_down" => CanEvent::InterfaceDown,
            "adapter_status" => {
                CanEvent::AdapterStatus { bus_off: flag("bus_off")?, error_passive: flag("error_passive")? }
            }
            other => return Err(format!("unknown CAN event `{other}`")),
        }),
        "can_failed" => RecordedInput::CanFailed,
        "can_reopened" => RecordedInput::CanReopened,
        "request" => RecordedInput::Request(Box::new(
            serde_json::from_value(field("request")?.clone()).map_err(|e| format!("`request`: {e}"))?,
        )),
        "vehicle_request" => RecordedInput::VehicleRequest {
            vehicle: field("vehicle")?
                .as_u64()
                .and_then(|k| u8::try_from(k).ok())
                .ok_or("`vehicle` is not a vehicle's index")?,
            request: Box::new(
                serde_json::from_value(field("request")?.clone()).map_err(|e| format!("`request`: {e}"))?,
            ),
        },
        "arm_at_start" => RecordedInput::ArmAtStart,
        "shutdown" => RecordedInput::Shutdown,
        "tick" => RecordedInput::Tick,
        other => return Err(format!("unknown input `{other}`")),
    };
    Ok(InputRecord { seq, at, input })
}
