//! The benchmark's report: its figures as JSON, its text, and the verdict on the floor.

use super::{sustained, BenchReport, Phase, Transport, Wire, BAUD, CAN_BITRATE};

impl BenchReport {
    pub(super) fn new(
        transport: &Transport,
        phases: Vec<Phase>,
        gateway_states: Vec<String>,
        other_states: Vec<(String, Vec<String>)>,
    ) -> Self {
        let sustained_samples_per_s = sustained(&phases, &|p| p.late_percent < 1.0);
        let sustained_vs_floor_samples_per_s =
            sustained(&phases, &|p| p.floor.is_some_and(|f| p.late_percent <= f.late_percent + 1.0));
        let wire = Wire::new();
        let (command, cia402) = match transport {
            Transport::SlcanPty => (wire.command_slcan_us, wire.cia402_slcan_us),
            Transport::SocketCan { .. } => (wire.command_frame_us, wire.cia402_frames_us),
        };
        BenchReport {
            transport: transport.describe(),
            wire_per_cycle_us: wire.sample_frame_us + command,
            wire_per_cycle_cia402_us: wire.sample_frame_us + cia402,
            wire,
            phases,
            sustained_samples_per_s,
            sustained_vs_floor_samples_per_s,
            gateway_states,
            other_states,
            planner_note: "planner per-evaluation figures: cargo bench --bench planner (docs/performance.md)",
        }
    }
}

impl BenchReport {
    /// The wire time a phase's latency is compared with.
    fn wire_for(&self, p: &Phase) -> f64 {
        if p.cia402 {
            self.wire_per_cycle_cia402_us
        } else {
            self.wire_per_cycle_us
        }
    }
}

impl std::fmt::Display for BenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.fmt_phases(f)?;
        self.fmt_added_and_stages(f)?;
        self.fmt_notes(f)
    }
}

impl BenchReport {
    /// The wire's figures, then a row a phase: rate, losses, latency, CPU, memory, floor.
    fn fmt_phases(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let w = &self.wire;
        writeln!(f, "flowgate bench over {}", self.transport)?;
        writeln!(
            f,
            "wire: one sample frame {:.0} µs at {} baud; one command frame {:.0} µs on CAN at {} bit/s ({:.0} µs as an SLCAN line); CiA 402: two RPDOs {:.0} µs ({:.0} µs as SLCAN lines)",
            w.sample_frame_us, BAUD, w.command_frame_us, CAN_BITRATE, w.command_slcan_us, w.cia402_frames_us, w.cia402_slcan_us
        )?;
        writeln!(
            f,
            "wire capacity: a frame of two samples and its end takes {:.0} µs, so the PSD line carries at most {:.0} samples/s; faster phases test flowgate beyond the wire",
            w.psd_frame_us, w.psd_max_samples_per_s
        )?;
        writeln!(
            f,
            "{:<38} {:>9} {:>9} {:>7} {:>7} {:>7} {:>7} {:>8} {:>7} {:>6} {:>13} {:>26} {:>5} {:>9}",
            "phase",
            "samples/s",
            "cycles",
            "lost",
            "late %",
            "p50 µs",
            "p99 µs",
            "p99.9 µs",
            "max µs",
            "CPU %",
            "RSS MB s/p/e",
            "floor p50/p99/late/CPU %",
            "lost",
            "p50/wire"
        )?;
        for p in &self.phases {
            let floor = match &p.floor {
                Some(fl) => {
                    format!(
                        "{:.0}/{:.0}/{:.2}/{:.1}",
                        fl.latency_us.p50, fl.latency_us.p99, fl.late_percent, fl.cpu_percent
                    )
                }
                None => "-".into(),
            };
            let floor_lost =
                p.floor.map_or("-".into(), |fl| (p.cycles_sent - fl.commands_received.min(p.cycles_sent)).to_string());
            writeln!(
                f,
                "{:<38} {:>9.0} {:>9} {:>7} {:>7.2} {:>7.0} {:>7.0} {:>8.0} {:>7.0} {:>6.1} {:>4.1}/{:>4.1}/{:>4.1} {:>26} {:>5} {:>9.2}",
                p.name,
                p.samples_per_s,
                p.cycles_sent,
                p.cycles_sent - p.commands_received.min(p.cycles_sent),
                p.late_percent,
                p.latency_us.p50,
                p.latency_us.p99,
                p.latency_us.p999,
                p.latency_us.max,
                p.cpu_percent,
                p.rss_mb[0],
                p.rss_mb[1],
                p.rss_mb[2],
                floor,
                floor_lost,
                p.latency_us.p50 / self.wire_for(p)
            )?;
        }
        Ok(())
    }

    /// What flowgate adds over its floor, and the gateway's stages, a row a phase.
    fn fmt_added_and_stages(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "\nwhat flowgate adds: the gateway's latency minus its floor's, quantile by quantile (µs)")?;
        writeln!(f, "{:<38} {:>8} {:>8} {:>8}", "phase", "p50", "p99", "p99.9")?;
        for p in &self.phases {
            if let Some(a) = &p.added_us {
                writeln!(f, "{:<38} {:>8.0} {:>8.0} {:>8.0}", p.name, a.p50, a.p99, a.p999)?;
            }
        }
        writeln!(f, "\nthe gateway's stages, as its loop measured them (µs, p50 / p99)")?;
        write!(f, "{:<38}", "phase")?;
        for s in self.phases.first().map_or(&[][..], |p| &p.stages[..]) {
            write!(f, " {:>15}", s.stage)?;
        }
        writeln!(f)?;
        for p in &self.phases {
            write!(f, "{:<38}", p.name)?;
            for s in &p.stages {
                write!(f, " {:>15}", format!("{:.2} / {:.2}", s.p50_us, s.p99_us))?;
            }
            writeln!(f)?;
        }
        Ok(())
    }

    /// What the columns mean, how each phase's gateway ran, and the sustained rates.
    fn fmt_notes(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f)?;
        writeln!(f, "lost: frames with no command; late: command after the next frame was due")?;
        writeln!(f, "floor: the same rate through a null gateway (its own process, same endpoints, no work): the pty, scheduler and CAN transport alone")?;
        writeln!(
            f,
            "p50/wire: median gateway-added latency over the wire time of one sample frame plus one command ({:.0} µs; with CiA 402 drives, plus two RPDOs: {:.0} µs)",
            self.wire_per_cycle_us, self.wire_per_cycle_cia402_us
        )?;
        writeln!(f, "gateway states: {}", self.gateway_states.join(" -> "))?;
        for p in self
            .phases
            .iter()
            .filter(|p| p.spin_us.is_some() || p.realtime.is_some() || p.recording || p.view || p.cia402 || p.ros2)
        {
            let mut how = Vec::new();
            if let Some(us) = p.spin_us {
                how.push(format!("[realtime] spin_us = {us} (its null gateway polling the same way)"));
            }
            if p.warm_up {
                how.push("warm_up = true (the cycle rehearsed as each window opens)".to_string());
            }
            if let Some(rt) = &p.realtime {
                how.push(format!("real-time settings {rt} (its null gateway with them too)"));
            }
            if p.recording {
                how.push("an MCAP recording of every input, output and cycle (`--record`)".to_string());
            }
            if p.view {
                how.push("the live view served (`--view`)".to_string());
            }
            if p.cia402 {
                how.push(
                    "two CiA 402 drives (an RPDO each a cycle; the latency to the second; its null gateway sends two)"
                        .to_string(),
                );
            }
            if p.ros2 {
                how.push("its ROS 2 node publishing (on loopback, no subscriber)".to_string());
            }
            let states =
                self.other_states.iter().find(|(n, _)| *n == p.name).map_or(String::new(), |(_, s)| s.join(" -> "));
            writeln!(
                f,
                "{}: another gateway with {}, in the same seconds; its states: {states}",
                p.name,
                how.join(" and ")
            )?;
        }
        writeln!(
            f,
            "sustained (with every slower phase): {:.0} samples/s with nothing lost and under 1% late; {:.0} samples/s with nothing lost and late no more than the floor + 1 point",
            self.sustained_samples_per_s, self.sustained_vs_floor_samples_per_s
        )
    }
}
