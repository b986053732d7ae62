//! The CAN endpoint a rig names (`can.url`), parsed: `socketcan:IFACE` or
//! `slcan:PATH?bitrate=BPS`. Configuration only; [`crate::gateway::shell::link`] opens it.

use std::path::PathBuf;
use std::str::FromStr;

use flowgate_protocol::slcan::Bitrate;

/// A CAN endpoint, parsed from its URL.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CanUrl {
    /// `socketcan:IFACE`
    SocketCan { interface: String },
    /// `slcan:PATH[?bitrate=BPS][&baud=BAUD]`
    Slcan { path: PathBuf, bitrate: u32, baud: u32 },
    /// `memory`: an in-process bus ([`crate::gateway::shell::link::memory`]), only in builds with the lab tools
    /// (tests); the deployed gateway's parser does not know it.
    #[cfg(feature = "lab")]
    Memory,
}

impl CanUrl {
    /// Whether the link's state must be polled (an SLCAN adapter says nothing unasked).
    pub fn polls_status(&self) -> bool {
        matches!(self, Self::Slcan { .. })
    }
}

impl FromStr for CanUrl {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = |why: &str| format!("CAN endpoint `{s}`: {why} (expected socketcan:IFACE or slcan:PATH?bitrate=BPS)");
        let (scheme, rest) = s.split_once(':').map_or((s, ""), |(a, b)| (a, b));
        match scheme {
            "socketcan" if rest.is_empty() => Err(bad("no interface named (socketcan:can0)")),
            "socketcan" if rest.starts_with('/') || rest.contains(['/', ' ', '?', ':']) || rest.len() > 15 => {
                Err(bad(&format!("`{rest}` is not an interface name (socketcan:can0, not socketcan://can0)")))
            }
            "socketcan" => Ok(Self::SocketCan { interface: rest.to_string() }),
            "slcan" if rest.is_empty() || rest.starts_with('?') => {
                Err(bad("no serial port named (slcan:/dev/ttyACM0)"))
            }
            "slcan" => {
                let (path, query) = rest.split_once('?').unwrap_or((rest, ""));
                let (mut bitrate, mut baud) = (1_000_000, 921_600);
                for kv in query.split('&').filter(|kv| !kv.is_empty()) {
                    let (k, v) = kv.split_once('=').ok_or_else(|| bad(&format!("`{kv}` is not key=value")))?;
                    let v: u32 = v.parse().map_err(|_| bad(&format!("`{v}` is not a number")))?;
                    match k {
                        "bitrate" => bitrate = v,
                        "baud" => baud = v,
                        _ => return Err(bad(&format!("unknown option `{k}`"))),
                    }
                }
                if baud == 0 {
                    return Err(bad("baud must be positive"));
                }
                if Bitrate::from_bps(bitrate).is_none() {
                    return Err(bad(&format!("bitrate {bitrate} is not one of SLCAN's S0-S8")));
                }
                Ok(Self::Slcan { path: path.into(), bitrate, baud })
            }
            #[cfg(feature = "lab")]
            "memory" => Ok(Self::Memory),
            _ => Err(bad("unknown scheme")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_urls() {
        assert_eq!("socketcan:vcan0".parse::<CanUrl>(), Ok(CanUrl::SocketCan { interface: "vcan0".into() }));
        assert_eq!(
            "slcan:/dev/ttyACM0?bitrate=500000".parse::<CanUrl>(),
            Ok(CanUrl::Slcan { path: "/dev/ttyACM0".into(), bitrate: 500_000, baud: 921_600 })
        );
        assert!("slcan:/dev/x?bitrate=123".parse::<CanUrl>().unwrap_err().contains("S0-S8"));
        assert!("slcan:/dev/x?speed=1".parse::<CanUrl>().unwrap_err().contains("unknown option `speed`"));
        assert!("can0".parse::<CanUrl>().unwrap_err().contains("unknown scheme"));
        for (url, why) in [
            ("socketcan:", "no interface named"),
            ("socketcan://can0", "is not an interface name"),
            ("slcan:", "no serial port named"),
            ("slcan:?bitrate=1000000", "no serial port named"),
            ("slcan:/dev/x?baud=0", "baud must be positive"),
        ] {
            let err = url.parse::<CanUrl>().unwrap_err();
            assert!(err.contains(why), "{url}: {err}");
        }
    }
}
