//! `[ros2]`: flowgate as a ROS 2 node (off by default). The domain and the discovery range
//! follow ROS 2's own environment (`ROS_DOMAIN_ID`, `ROS_AUTOMATIC_DISCOVERY_RANGE`) unless
//! the file sets them; [`Ros2Section::resolve`] reads that environment when the node starts.

use serde::{Deserialize, Serialize};

use super::checks::{invalid, Invalid};

/// The highest domain id ROS 2 allows on Linux (its ports stay below 65536 up to 232).
pub const MAX_DOMAIN_ID: u16 = 232;

/// Where DDS discovery looks for peers (ROS 2's `ROS_AUTOMATIC_DISCOVERY_RANGE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DiscoveryRange {
    /// This machine only: discovery and traffic on the loopback interface.
    Localhost,
    /// The machine's networks (ROS 2's default).
    Subnet,
}

impl DiscoveryRange {
    /// ROS 2's name for it, as in `ROS_AUTOMATIC_DISCOVERY_RANGE`.
    pub fn ros_name(self) -> &'static str {
        match self {
            Self::Localhost => "LOCALHOST",
            Self::Subnet => "SUBNET",
        }
    }
}

/// `[ros2]` as written.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Ros2Section {
    /// Join a ROS 2 system (default: no).
    #[serde(default)]
    pub enabled: bool,
    /// The DDS domain, 0-232; default: `ROS_DOMAIN_ID`, else 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub domain_id: Option<u16>,
    /// `"localhost"` or `"subnet"`; default: `ROS_AUTOMATIC_DISCOVERY_RANGE`, else subnet.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub discovery_range: Option<DiscoveryRange>,
    /// The node's namespace (`~/obstacles` is `<namespace>/<node_name>/obstacles`).
    #[serde(default = "default_namespace")]
    pub namespace: String,
    #[serde(default = "default_node_name")]
    pub node_name: String,
    /// The floor's frame: the calibrated floor coordinates (fixed in the room).
    #[serde(default = "default_floor_frame")]
    pub floor_frame: String,
    /// The robot's frame, at its centre, x forward.
    #[serde(default = "default_base_frame")]
    pub base_frame: String,
    /// Keep-last depth of every topic (reliable, volatile: what rclpy's defaults match).
    #[serde(default = "default_depth")]
    pub qos_depth: u16,
    /// How often `/odom`, `/tf`, `~/obstacles` and `~/path` are published, Hz
    /// (`/diagnostics`: once a second).
    #[serde(default = "default_rate")]
    pub publish_hz: f64,
    /// With `planner.method = "ros2"`: the topic the robot's velocity commands come on.
    #[serde(default = "default_cmd_vel")]
    pub cmd_vel: String,
    /// Take `geometry_msgs/TwistStamped` there instead of `Twist`.
    #[serde(default)]
    pub cmd_vel_stamped: bool,
}

fn default_namespace() -> String {
    "/".into()
}
fn default_node_name() -> String {
    "flowgate".into()
}
fn default_floor_frame() -> String {
    "map".into()
}
fn default_base_frame() -> String {
    "base_link".into()
}
fn default_depth() -> u16 {
    10
}
fn default_rate() -> f64 {
    20.0
}
fn default_cmd_vel() -> String {
    "/cmd_vel".into()
}

impl Default for Ros2Section {
    fn default() -> Self {
        Self {
            enabled: false,
            domain_id: None,
            discovery_range: None,
            namespace: default_namespace(),
            node_name: default_node_name(),
            floor_frame: default_floor_frame(),
            base_frame: default_base_frame(),
            qos_depth: default_depth(),
            publish_hz: default_rate(),
            cmd_vel: default_cmd_vel(),
            cmd_vel_stamped: false,
        }
    }
}

/// `[ros2]` resolved against the environment: what the node runs with.
#[derive(Debug, Clone, PartialEq)]
pub struct Ros2Settings {
    pub domain_id: u16,
    pub discovery_range: DiscoveryRange,
    pub namespace: String,
    pub node_name: String,
    pub floor_frame: String,
    pub base_frame: String,
    pub qos_depth: u16,
    pub publish_every: std::time::Duration,
    /// The topic of the robot's velocity commands and whether they are stamped, when an
    /// outside planner drives on ROS 2 (`planner.method = "ros2"`).
    pub cmd_vel: Option<(String, bool)>,
}

/// A ROS 2 name part: letters, digits and underscores, not starting with a digit.
pub(super) fn name_token(token: &str) -> bool {
    let mut chars = token.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

impl Ros2Section {
    pub(super) fn validate(&self) -> Result<(), Invalid> {
        if let Some(id) = self.domain_id.filter(|&id| id > MAX_DOMAIN_ID) {
            return invalid("ros2.domain_id", format!("is {id}: ROS 2 domains are 0-{MAX_DOMAIN_ID}"));
        }
        let ns = self.namespace.strip_prefix('/').filter(|rest| rest.is_empty() || rest.split('/').all(name_token));
        if ns.is_none() {
            return invalid(
                "ros2.namespace",
                format!("{:?} is not a ROS 2 namespace (\"/\" or \"/lab/rig_1\")", self.namespace),
            );
        }
        if !name_token(&self.node_name) {
            return invalid(
                "ros2.node_name",
                format!("{:?}: letters, digits and _, not starting with a digit", self.node_name),
            );
        }
        for (key, frame) in [("ros2.floor_frame", &self.floor_frame), ("ros2.base_frame", &self.base_frame)] {
            if frame.is_empty() || frame.contains(char::is_whitespace) {
                return invalid(key, format!("{frame:?} is not a frame id"));
            }
        }
        if self.floor_frame == self.base_frame {
            return invalid("ros2.base_frame", "is the floor frame: the robot needs a frame of its own");
        }
        if self.qos_depth == 0 {
            return invalid("ros2.qos_depth", "must be at least 1");
        }
        let topic = self.cmd_vel.strip_prefix('/').filter(|rest| !rest.is_empty() && rest.split('/').all(name_token));
        if topic.is_none() {
            return invalid(
                "ros2.cmd_vel",
                format!("{:?} is not an absolute ROS 2 topic (\"/cmd_vel\")", self.cmd_vel),
            );
        }
        if !(self.publish_hz.is_finite() && (0.1..=1000.0).contains(&self.publish_hz)) {
            return invalid("ros2.publish_hz", format!("must be 0.1-1000 Hz, is {}", self.publish_hz));
        }
        Ok(())
    }

    /// The settings, the file's over ROS 2's environment (`env`: `|name| std::env::var(name).ok()`).
    pub fn resolve(&self, env: impl Fn(&str) -> Option<String>) -> Result<Ros2Settings, Invalid> {
        let domain_id = match (self.domain_id, env("ROS_DOMAIN_ID").filter(|v| !v.trim().is_empty())) {
            (Some(id), _) => id,
            (None, Some(text)) => match text.trim().parse::<u16>() {
                Ok(id) if id <= MAX_DOMAIN_ID => id,
                _ => return invalid("ROS_DOMAIN_ID", format!("{text:?} is not a domain id 0-{MAX_DOMAIN_ID}")),
            },
            (None, None) => 0,
        };
        let discovery_range = match (self.discovery_range, env("ROS_AUTOMATIC_DISCOVERY_RANGE")) {
            (Some(range), _) => range,
            (None, Some(text)) => match text.trim() {
                "" | "SUBNET" | "SYSTEM_DEFAULT" => DiscoveryRange::Subnet,
                "LOCALHOST" => DiscoveryRange::Localhost,
                other => {
                    return invalid(
                        "ROS_AUTOMATIC_DISCOVERY_RANGE",
                        format!("{other:?}: flowgate takes LOCALHOST, SUBNET or SYSTEM_DEFAULT"),
                    )
                }
            },
            (None, None) => DiscoveryRange::Subnet,
        };
        Ok(Ros2Settings {
            domain_id,
            discovery_range,
            namespace: self.namespace.clone(),
            node_name: self.node_name.clone(),
            floor_frame: self.floor_frame.clone(),
            base_frame: self.base_frame.clone(),
            qos_depth: self.qos_depth,
            publish_every: std::time::Duration::from_secs_f64(1.0 / self.publish_hz),
            cmd_vel: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env<'a>(vars: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        move |name| vars.iter().find(|(k, _)| *k == name).map(|(_, v)| v.to_string())
    }

    /// ROS 2's environment sets the domain and the range unless the file does; a bad value
    /// is refused naming the variable, a bad key naming the key.
    #[test]
    fn the_file_wins_over_ros_environment() {
        let c = Ros2Section { enabled: true, ..Ros2Section::default() };
        let s = c.resolve(env(&[])).unwrap();
        assert_eq!((s.domain_id, s.discovery_range), (0, DiscoveryRange::Subnet));
        let ros = [("ROS_DOMAIN_ID", "42"), ("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")];
        let s = c.resolve(env(&ros)).unwrap();
        assert_eq!((s.domain_id, s.discovery_range), (42, DiscoveryRange::Localhost));
        let pinned = Ros2Section { domain_id: Some(7), discovery_range: Some(DiscoveryRange::Subnet), ..c.clone() };
        let s = pinned.resolve(env(&ros)).unwrap();
        assert_eq!((s.domain_id, s.discovery_range), (7, DiscoveryRange::Subnet));
        let e = c.resolve(env(&[("ROS_DOMAIN_ID", "300")])).unwrap_err();
        assert_eq!(e.key, "ROS_DOMAIN_ID");
        let e = c.resolve(env(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")])).unwrap_err();
        assert_eq!(e.key, "ROS_AUTOMATIC_DISCOVERY_RANGE");
        for (bad, key) in [
            (Ros2Section { domain_id: Some(233), ..c.clone() }, "ros2.domain_id"),
            (Ros2Section { namespace: "lab".into(), ..c.clone() }, "ros2.namespace"),
            (Ros2Section { namespace: "/lab/".into(), ..c.clone() }, "ros2.namespace"),
            (Ros2Section { node_name: "1gate".into(), ..c.clone() }, "ros2.node_name"),
            (Ros2Section { base_frame: "map".into(), ..c.clone() }, "ros2.base_frame"),
            (Ros2Section { qos_depth: 0, ..c.clone() }, "ros2.qos_depth"),
            (Ros2Section { publish_hz: 0.0, ..c.clone() }, "ros2.publish_hz"),
            (Ros2Section { cmd_vel: "cmd vel".into(), ..c.clone() }, "ros2.cmd_vel"),
        ] {
            assert_eq!(bad.validate().unwrap_err().key, key);
        }
        assert!(Ros2Section { namespace: "/lab/rig_1".into(), ..c }.validate().is_ok());
    }
}
