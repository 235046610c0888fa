//! What the console's page and the tool say to each other over the WebSocket: one JSON
//! object per message, `"type"` (to the page) or `"cmd"` (from it) naming its kind.
//! Units on the wire are the page's: time s, position mm, force N, pressure kPa, angle °.

use serde::{Deserialize, Serialize};

/// A control on the page: what it asks of the machine or the console.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(tag = "cmd", rename_all = "snake_case")]
pub enum Control {
    /// Find the zero.
    Home,
    /// Start compressing (or expanding) at a pressure ratio, at a peak speed (`None`: the
    /// paper's Fig. 3 speed for the ratio).
    Start {
        /// The pressure ratio: on the simulated board, the discharge line's; on the board it
        /// only chooses the speed (the line is the rig's).
        pressure_ratio: f64,
        /// Peak speed, m/s.
        speed_mps: Option<f64>,
        /// `compressor` or `expander`.
        rotation: String,
    },
    /// Stop at the next dead point and hold.
    Stop,
    /// Clear latched faults.
    ClearFaults,
    /// Run a calibration routine (`current-sense`, `alignment`, `misalignment`, `cogging`).
    Calibrate {
        /// The routine's name.
        routine: String,
    },
    /// Set the telemetry's rate and channels.
    Telemetry {
        /// Frames per second: 20000 divided by a whole number.
        rate_hz: f64,
        /// `gap`, `all` or channel names joined by commas.
        channels: String,
    },
    /// Arm the scope.
    ScopeArm {
        /// `command`, `fault`, `mode-change` or `strokes:N`.
        trigger: String,
        /// Samples before the trigger, 0–511.
        pre: u16,
    },
    /// Fire the scope (its `command` trigger).
    ScopeFire,
    /// Start or end recording the stream.
    Record {
        /// Start (`true`) or end (`false`).
        on: bool,
    },
}

/// A message to the page.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Message {
    /// What the console shows, sent once when the page connects.
    Hello {
        /// `sim`, `replay` or `probe`.
        mode: String,
        /// What is on the other end, for the title.
        source: String,
        /// `fpc-sim --version`.
        version: String,
    },
    /// Telemetry frames since the last batch, and the state of the last one.
    Frames(Batch),
    /// A line for the log under the controls: an answer of the firmware or the console's own.
    Log {
        /// The line.
        text: String,
        /// `ok`, `refused` (shown in red) or `info`.
        level: String,
    },
    /// A scope recording received whole: 20 kHz around its trigger.
    Scope(ScopeTrace),
    /// Whether the stream is being recorded, and where.
    Recording {
        /// Recording now.
        on: bool,
        /// The directory (being written, or written).
        dir: String,
    },
}

/// A batch of frames, column by column (absent channels are empty), and the state.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Batch {
    /// Board time of each frame, s since the console started (continuous: wraps of the
    /// firmware's µs counter and replay loops are unrolled).
    pub t: Vec<f64>,
    /// Piston position, mm.
    pub x: Vec<f32>,
    /// Its reference, mm (when the channel is streamed).
    pub x_ref: Vec<f32>,
    /// Master and slave section forces, N.
    pub f_master: Vec<f32>,
    /// Slave section force, N.
    pub f_slave: Vec<f32>,
    /// Chamber pressures, kPa.
    pub p_a: Vec<f32>,
    /// Chamber B, kPa.
    pub p_b: Vec<f32>,
    /// Rotation angle within a turn, °.
    pub theta: Vec<f32>,
    /// The last frame's mode (`idle`, `homing`, `holding`, `running`, …).
    pub mode: String,
    /// Homed.
    pub homed: bool,
    /// The first latched fault's name, if one is latched.
    pub fault: Option<String>,
    /// The parts absent since boot (`supply`, `encoders`, `pressures`): the board waits.
    pub absent: Vec<String>,
    /// The ports as declared.
    pub ports: String,
    /// Frames the firmware could not send so far.
    pub dropped: u16,
    /// Frames received since the console started.
    pub frames: u64,
    /// Frames lost between the firmware and the console (sequence gaps).
    pub gaps: u64,
    /// Telemetry frames rejected (framing, CRC).
    pub rejected: u64,
    /// How far the source is behind the wall clock, s (the simulated board stepping slower
    /// than real time; 0 for a replay or a board).
    pub behind_s: f64,
    /// Seconds since the last frame arrived (a board that stopped streaming).
    pub silent_s: f64,
}

/// A scope recording, columns in the page's units.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScopeTrace {
    /// Its number.
    pub id: u8,
    /// Its trigger, as typed.
    pub trigger: String,
    /// Time from the trigger, ms.
    pub t_ms: Vec<f64>,
    /// Position, mm.
    pub x: Vec<f64>,
    /// Section forces, N.
    pub f_master: Vec<f64>,
    /// Slave section force, N.
    pub f_slave: Vec<f64>,
    /// Chamber pressures, kPa.
    pub p_a: Vec<f64>,
    /// Chamber B, kPa.
    pub p_b: Vec<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn controls_read_as_the_page_sends_them() {
        let c: Control = serde_json::from_str(
            r#"{"cmd":"start","pressure_ratio":3.1,"speed_mps":null,"rotation":"compressor"}"#,
        )
        .unwrap();
        assert_eq!(
            c,
            Control::Start {
                pressure_ratio: 3.1,
                speed_mps: None,
                rotation: "compressor".into()
            }
        );
        let c: Control = serde_json::from_str(r#"{"cmd":"record","on":true}"#).unwrap();
        assert_eq!(c, Control::Record { on: true });
        assert!(serde_json::from_str::<Control>(r#"{"cmd":"launch"}"#).is_err());
    }

    #[test]
    fn messages_name_their_type() {
        let m = Message::Log {
            text: "accepted: home".into(),
            level: "ok".into(),
        };
        let text = serde_json::to_string(&m).unwrap();
        assert!(text.starts_with(r#"{"type":"log""#), "{text}");
        let text = serde_json::to_string(&Message::Frames(Batch::default())).unwrap();
        assert!(text.starts_with(r#"{"type":"frames""#), "{text}");
    }
}
