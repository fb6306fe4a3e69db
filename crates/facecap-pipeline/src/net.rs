//! Live outputs: each solved frame as OSC in the VMC protocol, as a Live Link Face UDP
//! packet, or as a JSON line, and the [`LiveSink`] that solves a frame and sends it at
//! once, timing each frame from its arrival to its packets.
//!
//! ## Values
//! The same numbers as the recorded files: the weights of `weights.csv` and, where the
//! rig's shape names map onto ARKit's ([`facecap_io::livelink::mapping`]), the ARKit curves
//! of `livelink.csv` (split `_L`/`_R` halves of an unsided shape averaged), head yaw,
//! pitch and roll as in `livelink.csv` ([`facecap_io::livelink::head_angles`]), and the eye
//! rotations of `livelink.csv` from the `eyeLook*` curves ([`eye_columns`]). Frames
//! without a face send no OSC or Live Link packet (receivers hold the last pose); the
//! JSON line says `"success": false`.
//!
//! ## VMC (OSC over UDP)
//! One OSC bundle per frame (immediate time tag): `/VMC/Ext/Blend/Val s:name f:value`
//! for every ARKit curve the rig feeds (ARKit's PascalCase names as in `livelink.csv`,
//! e.g. `JawOpen`: VSeeFace's perfect-sync clip names; the rig's own names when the rig
//! is not ARKit-named), then `/VMC/Ext/Blend/Apply`, then `/VMC/Ext/Bone/Pos s:Head
//! f:px f:py f:pz f:qx f:qy f:qz f:qw` with the head rotation as a quaternion in Unity's
//! axes of the avatar (x its right, y up, z forward: the subject facing the camera is the
//! identity; the head rotation relative to facing the camera,
//! [`facecap_core::camera::head_rotation`], has the same matrix in those axes because
//! both flips of camera axes to the subject's body axes cancel) and position 0 (the
//! head bone's offset stays the avatar's), then `/VMC/Ext/T f:seconds`.
//!
//! ## Live Link Face (UDP, Unreal's Apple ARKit Face Support, port 11111)
//! Big-endian (network order) packet, version 6:
//!
//! | bytes | field |
//! |---|---|
//! | 1 | version = 6 |
//! | 4 + n | device id: `i32` length, UTF-8 bytes |
//! | 4 + m | subject name: `i32` length, UTF-8 bytes |
//! | 4 + 4 | frame time: `i32` frame number, `f32` sub-frame |
//! | 4 + 4 | frame rate: `i32` numerator, `i32` denominator |
//! | 1 | curve count = 61 |
//! | 61 x 4 | `f32` curves in Unreal's `EARFaceBlendShape` order ([`PACKET_CURVES`]): 52 ARKit shapes, head yaw, pitch, roll, left eye yaw, pitch, roll, right eye yaw, pitch, roll |
//!
//! The order differs from the CSV's in two pairs (`JawLeft`/`JawRight`,
//! `MouthLeft`/`MouthRight`); values go by name.
//!
//! ## JSON lines
//! `{"frame", "timestamp", "success", "confidence", "weights": {rig name: value},
//! "pose": {"Tx".."Rz"} or null}`, one line per frame (pose as in `pose.csv`).

use std::io::Write;
use std::net::{ToSocketAddrs, UdpSocket};
use std::sync::mpsc::SyncSender;
use std::sync::Arc;
use std::time::Instant;

use facecap_core::camera::{head_rotation, pose_row};
use image::GrayImage;
use nalgebra::UnitQuaternion;
use rosc::{OscBundle, OscMessage, OscPacket, OscTime, OscType};

use crate::error::{BoxError, Error, Result};
use crate::expression::{ExpressionResult, ExpressionSink, SolvedFrame};
use crate::live::ArrivalLog;
use crate::sink::{FrameImages, Sink, TrackedFace};
use facecap_io::livelink::{head_angles, mapping, LIVE_LINK_POSE, LIVE_LINK_SHAPES};

/// The 61 curves of a Live Link Face packet, in Unreal's `EARFaceBlendShape` order.
pub const PACKET_CURVES: [&str; 61] = [
    "EyeBlinkLeft",
    "EyeLookDownLeft",
    "EyeLookInLeft",
    "EyeLookOutLeft",
    "EyeLookUpLeft",
    "EyeSquintLeft",
    "EyeWideLeft",
    "EyeBlinkRight",
    "EyeLookDownRight",
    "EyeLookInRight",
    "EyeLookOutRight",
    "EyeLookUpRight",
    "EyeSquintRight",
    "EyeWideRight",
    "JawForward",
    "JawLeft",
    "JawRight",
    "JawOpen",
    "MouthClose",
    "MouthFunnel",
    "MouthPucker",
    "MouthLeft",
    "MouthRight",
    "MouthSmileLeft",
    "MouthSmileRight",
    "MouthFrownLeft",
    "MouthFrownRight",
    "MouthDimpleLeft",
    "MouthDimpleRight",
    "MouthStretchLeft",
    "MouthStretchRight",
    "MouthRollLower",
    "MouthRollUpper",
    "MouthShrugLower",
    "MouthShrugUpper",
    "MouthPressLeft",
    "MouthPressRight",
    "MouthLowerDownLeft",
    "MouthLowerDownRight",
    "MouthUpperUpLeft",
    "MouthUpperUpRight",
    "BrowDownLeft",
    "BrowDownRight",
    "BrowInnerUp",
    "BrowOuterUpLeft",
    "BrowOuterUpRight",
    "CheekPuff",
    "CheekSquintLeft",
    "CheekSquintRight",
    "NoseSneerLeft",
    "NoseSneerRight",
    "TongueOut",
    "HeadYaw",
    "HeadPitch",
    "HeadRoll",
    "LeftEyeYaw",
    "LeftEyePitch",
    "LeftEyeRoll",
    "RightEyeYaw",
    "RightEyePitch",
    "RightEyeRoll",
];

/// Live Link Face packet version.
pub const LIVE_LINK_PACKET_VERSION: u8 = 6;

/// A UDP socket bound to an ephemeral local port and connected to `target` (`HOST:PORT`).
///
/// # Errors
/// A target that does not resolve, or a socket that cannot be opened.
pub fn udp_to(target: &str) -> Result<UdpSocket> {
    let bad = |why: String| Error::invalid("UDP target", target, format!("HOST:PORT ({why})"));
    let addr = target
        .to_socket_addrs()
        .map_err(|e| bad(e.to_string()))?
        .next()
        .ok_or_else(|| bad("no address".into()))?;
    let local = if addr.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" };
    let s = UdpSocket::bind(local).map_err(|e| bad(e.to_string()))?;
    s.connect(addr).map_err(|e| bad(e.to_string()))?;
    Ok(s)
}

/// The weights a frame sends, by name: ARKit curves (CSV order, mapped) when the rig
/// maps onto ARKit, else the rig's own.
#[derive(Debug, Clone)]
pub struct CurveMap {
    /// Per rig shape: (column in `LIVE_LINK_SHAPES`, share), when the rig maps.
    arkit: Option<Vec<(usize, f64)>>,
    /// The names sent over VMC, in order.
    names: Vec<String>,
    /// For ARKit rigs, the `LIVE_LINK_SHAPES` column of each sent name.
    columns: Vec<usize>,
}

impl CurveMap {
    /// The map of a rig with these shape names.
    pub fn new(rig_names: &[String]) -> Self {
        match mapping(rig_names) {
            Some(m) => {
                let mut columns: Vec<usize> = m.iter().map(|(c, _)| *c).collect();
                columns.sort_unstable();
                columns.dedup();
                CurveMap {
                    names: columns.iter().map(|&c| LIVE_LINK_SHAPES[c].to_string()).collect(),
                    columns,
                    arkit: Some(m),
                }
            }
            None => CurveMap {
                arkit: None,
                names: rig_names.to_vec(),
                columns: Vec::new(),
            },
        }
    }

    /// Whether the rig maps onto ARKit.
    pub fn is_arkit(&self) -> bool {
        self.arkit.is_some()
    }

    /// The 52 ARKit values in `LIVE_LINK_SHAPES` (CSV) order, as in `livelink.csv`.
    pub fn arkit_values(&self, weights: &[f64]) -> [f64; 52] {
        self.arkit
            .as_ref()
            .map_or([0.0; 52], |m| facecap_io::livelink::arkit_values(m, weights))
    }

    /// (name, value) pairs sent over VMC.
    pub fn named_values(&self, weights: &[f64]) -> Vec<(&str, f64)> {
        if self.arkit.is_some() {
            let v = self.arkit_values(weights);
            self.names
                .iter()
                .zip(&self.columns)
                .map(|(n, &c)| (n.as_str(), v[c]))
                .collect()
        } else {
            self.names
                .iter()
                .map(String::as_str)
                .zip(weights.iter().copied())
                .collect()
        }
    }
}

/// One frame's VMC bundle (module docs), encoded.
///
/// # Errors
/// When rosc cannot encode the bundle.
pub fn vmc_packet(curves: &CurveMap, frame: &SolvedFrame) -> Result<Vec<u8>> {
    let msg = |addr: &str, args: Vec<OscType>| {
        OscPacket::Message(OscMessage {
            addr: addr.to_string(),
            args,
        })
    };
    let mut content: Vec<OscPacket> = curves
        .named_values(&frame.weights)
        .into_iter()
        .map(|(n, v)| {
            msg(
                "/VMC/Ext/Blend/Val",
                vec![OscType::String(n.to_string()), OscType::Float(v as f32)],
            )
        })
        .collect();
    content.push(msg("/VMC/Ext/Blend/Apply", vec![]));
    let q = match &frame.pose {
        Some(p) => UnitQuaternion::from_rotation_matrix(&head_rotation(p)),
        None => UnitQuaternion::identity(),
    };
    content.push(msg(
        "/VMC/Ext/Bone/Pos",
        vec![
            OscType::String("Head".into()),
            OscType::Float(0.0),
            OscType::Float(0.0),
            OscType::Float(0.0),
            OscType::Float(q.i as f32),
            OscType::Float(q.j as f32),
            OscType::Float(q.k as f32),
            OscType::Float(q.w as f32),
        ],
    ));
    content.push(msg("/VMC/Ext/T", vec![OscType::Float(frame.timestamp as f32)]));
    let bundle = OscPacket::Bundle(OscBundle {
        timetag: OscTime {
            seconds: 0,
            fractional: 1,
        },
        content,
    });
    rosc::encoder::encode(&bundle).map_err(|e| Error::Sink {
        sink: "osc".into(),
        source: Box::new(std::io::Error::other(format!("{e:?}"))),
    })
}

/// The Live Link eye columns (`LeftEyeYaw` .. `RightEyeRoll`, radians) of a frame's 52 ARKit
/// values (`LIVE_LINK_SHAPES` order): its `eyeLook*` weights turned into eye rotations
/// ([`facecap_landmarks::gaze::eye_rotations`] with the gains the pipeline's gaze uses); roll 0.
pub fn eye_columns(arkit: &[f64; 52]) -> [f64; 6] {
    use facecap_landmarks::gaze::{eye_rotations, GazeGains, GAZE_WEIGHT_NAMES};
    let mut look = [0.0; 8];
    for (slot, name) in look.iter_mut().zip(GAZE_WEIGHT_NAMES) {
        if let Some(c) = LIVE_LINK_SHAPES.iter().position(|s| s.eq_ignore_ascii_case(name)) {
            *slot = arkit[c];
        }
    }
    let [[ly, lp], [ry, rp]] = eye_rotations(&look, &GazeGains::default());
    [ly, lp, 0.0, ry, rp, 0.0]
}

/// The 61 packet curves of a frame (module docs): ARKit values then head and eyes.
pub fn packet_curves(curves: &CurveMap, frame: &SolvedFrame) -> [f32; 61] {
    let csv = curves.arkit_values(&frame.weights);
    let head = head_angles(frame.pose.as_ref());
    let eyes = eye_columns(&csv);
    let mut out = [0.0f32; 61];
    for (slot, name) in out.iter_mut().zip(PACKET_CURVES) {
        *slot = if let Some(c) = LIVE_LINK_SHAPES.iter().position(|s| *s == name) {
            csv[c] as f32
        } else {
            match LIVE_LINK_POSE.iter().position(|s| *s == name) {
                Some(k) if k < 3 => head[k] as f32,
                Some(k) => eyes[k - 3] as f32,
                None => 0.0,
            }
        };
    }
    out
}

/// One frame's Live Link Face packet (module docs). `fps` is rounded to a whole
/// numerator over 1.
pub fn live_link_packet(device: &str, subject: &str, frame_number: i32, fps: f64, curves: &[f32; 61]) -> Vec<u8> {
    let mut b = Vec::with_capacity(32 + device.len() + subject.len() + 4 * curves.len());
    b.push(LIVE_LINK_PACKET_VERSION);
    for s in [device, subject] {
        b.extend_from_slice(&(s.len() as i32).to_be_bytes());
        b.extend_from_slice(s.as_bytes());
    }
    b.extend_from_slice(&frame_number.to_be_bytes());
    b.extend_from_slice(&0.0f32.to_be_bytes());
    let rate = if fps.is_finite() && fps >= 1.0 {
        fps.round() as i32
    } else {
        30
    };
    b.extend_from_slice(&rate.to_be_bytes());
    b.extend_from_slice(&1i32.to_be_bytes());
    b.push(curves.len() as u8);
    for v in curves {
        b.extend_from_slice(&v.to_be_bytes());
    }
    b
}

/// One frame as a JSON line (module docs), without the newline.
pub fn json_line(names: &[String], frame: &SolvedFrame) -> String {
    let weights: serde_json::Map<String, serde_json::Value> = names
        .iter()
        .zip(&frame.weights)
        .map(|(n, &w)| {
            (
                n.clone(),
                if frame.success {
                    serde_json::json!(w)
                } else {
                    serde_json::Value::Null
                },
            )
        })
        .collect();
    let pose = frame.pose.as_ref().map(|p| {
        let r = pose_row(Some(p));
        serde_json::json!({"Tx": r[0], "Ty": r[1], "Tz": r[2], "Rx": r[3], "Ry": r[4], "Rz": r[5]})
    });
    serde_json::json!({
        "frame": frame.index,
        "timestamp": frame.timestamp,
        "success": frame.success,
        "confidence": frame.confidence,
        "weights": weights,
        "pose": pose,
    })
    .to_string()
}

/// Where JSON lines go.
#[derive(Debug)]
pub enum JsonTarget {
    /// Standard output.
    Stdout,
    /// A UDP datagram per line.
    Udp(UdpSocket),
}

/// The network and stdout outputs of a live run.
#[derive(Debug, Default)]
pub struct LiveOutputs {
    /// VMC over OSC.
    pub osc: Option<UdpSocket>,
    /// Live Link Face packets.
    pub livelink: Option<UdpSocket>,
    /// JSON lines.
    pub json: Option<JsonTarget>,
    /// Live Link subject name.
    pub subject: String,
    /// Live Link device id.
    pub device: String,
    /// Stream frame rate (Live Link frame rate field).
    pub fps: f64,
}

/// What the preview window gets per frame (newest first: frames it has no time for are
/// skipped).
#[derive(Debug, Clone)]
pub struct PreviewFrame {
    /// The grey camera frame.
    pub gray: Arc<GrayImage>,
    /// The solved frame.
    pub solved: SolvedFrame,
    /// Frames per second processed over the last second.
    pub fps: f64,
    /// This frame's latency, arrival to packets, ms.
    pub latency_ms: f64,
    /// Frames dropped so far.
    pub dropped: u64,
}

/// Counters and per-frame latencies of a live run.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LiveReport {
    /// Frames solved and sent.
    pub frames: u64,
    /// OSC bundles sent.
    pub osc_packets: u64,
    /// Live Link packets sent.
    pub livelink_packets: u64,
    /// JSON lines written.
    pub json_lines: u64,
    /// UDP sends that failed (e.g. nobody listening: ICMP port unreachable).
    pub send_errors: u64,
    /// (stream seconds, latency ms) per frame whose arrival is known.
    pub latencies: Vec<(f64, f64)>,
}

/// Solves each frame ([`ExpressionSink`]) and sends it to every output at once.
pub struct LiveSink<'a> {
    solve: ExpressionSink<'a>,
    outputs: LiveOutputs,
    curves: CurveMap,
    arrivals: ArrivalLog,
    preview: Option<SyncSender<PreviewFrame>>,
    dropped: Arc<crate::live::LiveStats>,
    recent: std::collections::VecDeque<Instant>,
    report: LiveReport,
    on_neutral: Option<NeutralCallback<'a>>,
    neutrals_seen: u32,
}

/// Called with each live neutral calibration's entry when it is applied (or failed).
pub type NeutralCallback<'a> = Box<dyn FnMut(&serde_json::Value) + Send + 'a>;

impl std::fmt::Debug for LiveSink<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveSink")
            .field("outputs", &self.outputs)
            .field("frames", &self.report.frames)
            .finish()
    }
}

impl<'a> LiveSink<'a> {
    /// Wraps `solve`; `arrivals` and `stats` come from the [`crate::live::LatestFrame`]
    /// source; `preview` gets each frame with its image when it is free.
    pub fn new(
        solve: ExpressionSink<'a>,
        outputs: LiveOutputs,
        arrivals: ArrivalLog,
        stats: Arc<crate::live::LiveStats>,
        preview: Option<SyncSender<PreviewFrame>>,
    ) -> Self {
        LiveSink {
            curves: CurveMap::new(solve.names()),
            solve,
            outputs,
            arrivals,
            preview,
            dropped: stats,
            recent: std::collections::VecDeque::new(),
            report: LiveReport::default(),
            on_neutral: None,
            neutrals_seen: 0,
        }
    }

    /// Calls `f` with each live neutral calibration when it is applied.
    pub fn on_neutral(mut self, f: NeutralCallback<'a>) -> Self {
        self.on_neutral = Some(f);
        self
    }

    /// Live calibrations taken so far.
    pub fn neutrals_taken(&self) -> u32 {
        self.solve.live_neutrals_taken()
    }

    /// Commits the solve's CSVs; returns its result and the live report.
    ///
    /// # Errors
    /// As [`ExpressionSink::finish`].
    pub fn finish(self) -> Result<(ExpressionResult, LiveReport)> {
        Ok((self.solve.finish()?, self.report))
    }

    fn send(&mut self, frame: &SolvedFrame) -> Result<()> {
        let io_err = |sink: &str, e: std::io::Error| Error::Sink {
            sink: sink.to_string(),
            source: Box::new(e) as BoxError,
        };
        if frame.success {
            if let Some(s) = &self.outputs.osc {
                let p = vmc_packet(&self.curves, frame)?;
                match s.send(&p) {
                    Ok(_) => self.report.osc_packets += 1,
                    Err(_) => self.report.send_errors += 1,
                }
            }
            if let Some(s) = &self.outputs.livelink {
                let curves = packet_curves(&self.curves, frame);
                let p = live_link_packet(
                    &self.outputs.device,
                    &self.outputs.subject,
                    i32::try_from(frame.index).unwrap_or(i32::MAX),
                    self.outputs.fps,
                    &curves,
                );
                match s.send(&p) {
                    Ok(_) => self.report.livelink_packets += 1,
                    Err(_) => self.report.send_errors += 1,
                }
            }
        }
        match &self.outputs.json {
            Some(JsonTarget::Stdout) => {
                let mut line = json_line(self.solve.names(), frame);
                line.push('\n');
                let mut out = std::io::stdout().lock();
                out.write_all(line.as_bytes())
                    .and_then(|_| out.flush())
                    .map_err(|e| io_err("json", e))?;
                self.report.json_lines += 1;
            }
            Some(JsonTarget::Udp(s)) => match s.send(json_line(self.solve.names(), frame).as_bytes()) {
                Ok(_) => self.report.json_lines += 1,
                Err(_) => self.report.send_errors += 1,
            },
            None => {}
        }
        Ok(())
    }
}

impl Sink for LiveSink<'_> {
    fn name(&self) -> &str {
        "live"
    }

    fn images(&self) -> FrameImages {
        if self.preview.is_some() {
            FrameImages::Every
        } else {
            FrameImages::None
        }
    }

    fn wants_iris(&self) -> bool {
        self.solve.wants_iris()
    }

    fn frame(&mut self, face: &TrackedFace) -> Result<()> {
        self.solve.frame(face)?;
        if let (Some(f), serde_json::Value::Array(entries)) = (self.on_neutral.as_mut(), self.solve.neutral_report()) {
            for e in entries.iter().skip(self.neutrals_seen as usize) {
                f(e);
            }
            self.neutrals_seen = entries.len() as u32;
        }
        let Some(frame) = self.solve.last_frame().cloned() else {
            return Ok(());
        };
        self.send(&frame)?;
        let now = Instant::now();
        let latency_ms = self
            .arrivals
            .arrival(face.index)
            .map(|a| now.duration_since(a).as_secs_f64() * 1e3);
        if let Some(l) = latency_ms {
            self.report.latencies.push((face.timestamp, l));
        }
        self.report.frames += 1;
        self.recent.push_back(now);
        while self
            .recent
            .front()
            .is_some_and(|t| now.duration_since(*t).as_secs_f64() > 1.0)
        {
            self.recent.pop_front();
        }
        if let (Some(tx), Some(gray)) = (&self.preview, &face.gray) {
            // newest first: a busy window misses this frame rather than delaying any
            let _ = tx.try_send(PreviewFrame {
                gray: gray.clone(),
                solved: frame,
                fps: self.recent.len() as f64,
                latency_ms: latency_ms.unwrap_or(f64::NAN),
                dropped: self.dropped.dropped.load(std::sync::atomic::Ordering::Relaxed),
            });
        }
        Ok(())
    }

    fn end(&mut self) -> Result<()> {
        self.solve.end()
    }
}

/// `p`-quantile (0..=1) of `values` (nearest rank); NaN when empty.
pub fn quantile(values: &[f64], p: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let rank = ((p.clamp(0.0, 1.0) * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[rank - 1]
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// A look towards the subject's right (image left) turns both eyes to positive yaw, a
    /// look down to positive pitch, as the head's yaw and pitch; no gaze, no rotation.
    #[test]
    fn eye_columns_follow_the_head_signs() {
        let at = |pairs: &[(&str, f64)]| {
            let mut v = [0.0; 52];
            for (n, w) in pairs {
                v[LIVE_LINK_SHAPES.iter().position(|s| s == n).unwrap()] = *w;
            }
            eye_columns(&v)
        };
        let right = at(&[("EyeLookOutRight", 0.4), ("EyeLookInLeft", 0.4)]);
        assert!(right[0] > 0.1 && right[3] > 0.1, "{right:?}");
        let left = at(&[("EyeLookInRight", 0.4), ("EyeLookOutLeft", 0.4)]);
        assert!(left[0] < -0.1 && left[3] < -0.1, "{left:?}");
        let down = at(&[("EyeLookDownRight", 0.3), ("EyeLookDownLeft", 0.3)]);
        assert!(down[1] > 0.1 && down[4] > 0.1 && down[0] == 0.0, "{down:?}");
        let up = at(&[("EyeLookUpRight", 0.3), ("EyeLookUpLeft", 0.3)]);
        assert!(up[1] < -0.1 && up[4] < -0.1, "{up:?}");
        assert_eq!(at(&[]), [0.0; 6]);
        // saturated weights stay within the human range of eye movement
        let far = at(&[("EyeLookInLeft", 1.0), ("EyeLookDownRight", 1.0)]);
        assert!(far.iter().all(|a| a.abs() <= 50f64.to_radians() + 1e-12), "{far:?}");
        // roll is never estimated
        assert_eq!((far[2], far[5]), (0.0, 0.0));
    }

    fn frame(weights: Vec<f64>) -> SolvedFrame {
        SolvedFrame {
            index: 7,
            timestamp: 0.25,
            success: true,
            confidence: 0.9,
            landmarks: None,
            weights,
            pose: None,
            reprojection_px: 0.0,
        }
    }

    #[test]
    fn vmc_bundle_decodes_with_rosc() {
        let names: Vec<String> = ["jawOpen", "browInnerUp_L", "browInnerUp_R"].map(String::from).to_vec();
        let c = CurveMap::new(&names);
        let p = vmc_packet(&c, &frame(vec![0.5, 0.2, 0.4])).unwrap();
        let (_, pkt) = rosc::decoder::decode_udp(&p).unwrap();
        let OscPacket::Bundle(b) = pkt else {
            panic!("not a bundle")
        };
        let msgs: Vec<OscMessage> = b
            .content
            .into_iter()
            .filter_map(|p| match p {
                OscPacket::Message(m) => Some(m),
                OscPacket::Bundle(_) => None,
            })
            .collect();
        assert_eq!(msgs[0].addr, "/VMC/Ext/Blend/Val");
        // ARKit order of livelink.csv: JawOpen (17) before BrowInnerUp (43), halves averaged
        assert_eq!(
            msgs[0].args,
            vec![OscType::String("JawOpen".into()), OscType::Float(0.5)]
        );
        assert_eq!(
            msgs[1].args,
            vec![OscType::String("BrowInnerUp".into()), OscType::Float(0.3f64 as f32)]
        );
        assert_eq!(msgs[2].addr, "/VMC/Ext/Blend/Apply");
        assert_eq!(msgs[3].addr, "/VMC/Ext/Bone/Pos");
        assert_eq!(msgs[3].args.len(), 8);
        assert_eq!(msgs[3].args[7], OscType::Float(1.0));
    }

    #[test]
    fn live_link_packet_layout() {
        let names: Vec<String> = ["jawOpen", "mouthLeft"].map(String::from).to_vec();
        let c = CurveMap::new(&names);
        let curves = packet_curves(&c, &frame(vec![0.75, 0.25]));
        let p = live_link_packet("dev", "face", 7, 29.97, &curves);
        assert_eq!(p.len(), 1 + 4 + 3 + 4 + 4 + 16 + 1 + 61 * 4);
        assert_eq!(p[0], 6);
        assert_eq!(&p[1..5], &3i32.to_be_bytes());
        assert_eq!(&p[5..8], b"dev");
        let t = 8 + 4 + 4;
        assert_eq!(&p[t..t + 4], &7i32.to_be_bytes());
        assert_eq!(&p[t + 8..t + 12], &30i32.to_be_bytes());
        assert_eq!(p[t + 16], 61);
        let f = |k: usize| {
            let o = t + 17 + 4 * k;
            f32::from_be_bytes([p[o], p[o + 1], p[o + 2], p[o + 3]])
        };
        assert_eq!(f(17), 0.75); // JawOpen
        assert_eq!(f(21), 0.25); // MouthLeft: index 21 in the packet (22 in the CSV)
        assert_eq!(f(22), 0.0);
    }

    #[test]
    fn quantiles() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&v, 0.5), 50.0);
        assert_eq!(quantile(&v, 0.99), 99.0);
        assert!(quantile(&[], 0.5).is_nan());
    }
}
