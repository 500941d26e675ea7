//! `stereotac process`: the live pipeline, offline, on a recording. The frames are read
//! in file order and routed exactly as `run` routed them, so the depth maps are the same
//! bit for bit; tactile pairs are reconstructed in parallel (rayon), stereo frames in
//! order (the temporal filter has state). The model and calibration stored in the
//! recording are used unless others are given.

use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::atomic::Ordering;

use anyhow::{Context, Result, bail};
use foxglove::Decode;
use stereotac::describe;
use stereotac::live::{Job, Pipeline, PipelineError, check_ambient};
use stereotac::recording::content::{self, Content};
use stereotac::recording::messages::{ClockInfo, PhaseInfo};
use stereotac::recording::reader::{self, Record, RecordingHeader};
use stereotac::recording::topics;
use stereotac::recording::writer::{Item, Recorder, RecorderOptions};
use stereotac::stereo::StereoCalibration;
use stereotac::tactile::model::TactileModel;

use crate::console::{interrupt_flag, naming_file};
use crate::live_report::Report;
use crate::progress::bar;
use crate::stages::{
    META_STEREO, REFERENCE_DX, REFERENCE_DY, SizeFix, StageArgs, StereoSetup, TactileSetup,
    from_png, stereo_settings,
};
use stereotac::recording::metadata::stamp_ref_of;

/// `stereotac process`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The recording (MCAP, from `run` or `record`).
    pub recording: PathBuf,
    /// Tactile model and stereo calibration (default: the ones the recording holds).
    #[command(flatten)]
    pub stages: StageArgs,
    /// Read past the model's reach (the light model reads steeper walls where the
    /// table's or perceptron's slopes reach the calibration's limit) even where the
    /// recording's run had it off (`run --no-past-reach`).
    #[arg(long, conflicts_with = "no_past_reach")]
    pub past_reach: bool,
    /// Write the frames, depth maps, contact summaries and point clouds to this new
    /// MCAP file.
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// One JSON object per tactile pair on stdout (as `run --jsonl`; latency is null
    /// offline).
    #[arg(long)]
    pub jsonl: bool,
}

/// Jobs gathered before a parallel batch runs.
const BATCH: usize = 16;

pub fn run(a: Args) -> Result<()> {
    // Ctrl-C or SIGTERM stops the reading; what was read is processed and the output
    // file finished, then the run says where it stopped (a killed run left a cut output
    // and no word).
    let stop = interrupt_flag()?;
    let mut interrupted_at = None;
    if a.recording.is_dir() {
        bail!(
            "{} is a folder: `process` reads an MCAP recording (`record --out FILE.mcap`, \
             `run --mcap`); a `record --png` folder's frames are PNG files with an \
             index.jsonl, not pairs process can take",
            a.recording.display()
        );
    }
    let header =
        reader::header(&a.recording).map_err(|e| naming_file(e, "reading", &a.recording))?;
    let (tactile, stereo) = setups(&a, &header)?;
    let run_meta = header.metadata.get(topics::META_RECORDING);
    let mode = run_meta.and_then(|m| describe::mode_named(m.get("mode")?));
    if let (Some(t), Some(mode)) = (&tactile, mode) {
        check_ambient(&t.model, mode, t.static_ambient).map_err(|e| {
            anyhow::anyhow!(
                "{}: {e}: give a model calibrated without LEDs-off frames (--model), or \
                 pass --static-ambient to remove the ambient light measured at calibration \
                 instead (wrong once the room's light changes)",
                a.recording.display()
            )
        })?;
    }
    if tactile.is_none() && stereo.is_none() {
        // A file cut short may have lost them with the rest: said first.
        let cut = header
            .truncated
            .as_ref()
            .map(|why| format!(" (the file is cut short or damaged: {why})"))
            .unwrap_or_default();
        bail!(
            "{}: nothing to process: it holds no tactile model and no stereo calibration{cut}; \
             give --model FILE (dx/dy pairs → tactile depth) or --calib FILE (two cameras' \
             dark frames → stereo depth)",
            a.recording.display()
        );
    }
    let stamp = |camera| stamp_ref_of(run_meta, camera).map_err(anyhow::Error::msg);
    let origin_ns = run_meta
        .and_then(|m| m.get("clock_origin_unix_ns"))
        .map(|v| {
            v.parse::<u64>().with_context(|| {
                format!("metadata `stereotac` entry `clock_origin_unix_ns`: {v:?} is not a number")
            })
        })
        .transpose()?
        .unwrap_or(0);
    // Stopped while the header was read: nothing is written.
    if stop.load(Ordering::SeqCst) {
        bail!(
            "interrupted before processing began: nothing was written ({})",
            a.recording.display()
        );
    }
    let recorder = Recorder::start(RecorderOptions {
        mcap: a.mcap.clone(),
        live_view: None,
        queue: 2 * BATCH,
        wait_when_full: true,
        clock_origin_unix_ns: origin_ns,
    })?;
    for (name, entries) in &header.metadata {
        if name != "drops" && name != META_STEREO && name != "tactile_settings" {
            let mut entries = entries.clone();
            if name == topics::META_RECORDING {
                entries.insert("command".into(), "process".into());
                entries.insert("source".into(), a.recording.display().to_string());
            }
            recorder.send(Item::Metadata {
                name: name.clone(),
                entries,
            });
        }
    }
    if let Some(t) = &tactile {
        t.record(&recorder)?;
    }
    if let Some(s) = &stereo {
        s.record(&recorder)?;
    }
    let tactile_stage = tactile.as_ref().map(|t| t.stage(stamp(0)?)).transpose()?;
    let stereo_stage = stereo
        .as_ref()
        .map(|s| s.stage([stamp(0)?, stamp(1)?]))
        .transpose()?;
    let mut pipeline = Pipeline::new(tactile_stage, stereo_stage);
    let mut report = Report::new(a.jsonl);
    let mut jobs = Vec::new();
    let mut last_sequence: BTreeMap<usize, u64> = BTreeMap::new();
    let mut dropped = 0u64;
    let mut sizes_checked = [false; 2];
    let progress = bar(1, "processing");
    // Runs the gathered jobs; `false` once stdout is gone (then processing stops, and
    // the output file is still finished).
    let mut flush = |jobs: &mut Vec<Job>, pipeline: &mut Pipeline, dropped| -> Result<bool> {
        let mut open = true;
        let outputs = pipeline.run_batch(jobs, || None, dropped);
        for (job, output) in jobs.iter().zip(outputs) {
            let output = match output {
                // This pair's depth cannot be right; the next may be: warn and go on.
                Err(PipelineError::Tactile(e)) if e.refuses_this_pair_only() => {
                    let message = format!("tactile pair refused: {e}");
                    eprintln!("warning: {message}");
                    let at_us = match job {
                        Job::Tactile(pair) => pair.dy.frame.stamp.timestamp_us,
                        Job::Stereo(pair) => pair.left.frame.stamp.timestamp_us,
                    };
                    recorder.send(Item::Warning { at_us, message });
                    continue;
                }
                output => output?,
            };
            let Some(output) = output else { continue };
            open = open && report.print(&output)?;
            recorder.send(output.into_item());
        }
        jobs.clear();
        Ok(open)
    };
    let mut stdout_open = true;
    let read = content::frames(
        &a.recording,
        |content, (done, len)| -> Result<ControlFlow<()>> {
            progress.set_length(len.max(1));
            progress.set_position(done);
            if stop.load(Ordering::SeqCst) {
                interrupted_at = Some((done, len));
                return Ok(ControlFlow::Break(()));
            }
            let frame = match content {
                Content::Frame(f) => f,
                Content::Other(Record::Message {
                    topic,
                    data,
                    log_time_ns,
                    ..
                }) => {
                    pass_through(&recorder, &topic, &data, log_time_ns, origin_ns);
                    return Ok(ControlFlow::Continue(()));
                }
                Content::Other(_) => return Ok(ControlFlow::Continue(())),
            };
            let camera = frame.camera;
            if let Some(prev) = last_sequence.insert(camera, frame.info.sequence) {
                dropped += frame.info.sequence.saturating_sub(prev + 1);
            }
            if camera < 2 && !std::mem::replace(&mut sizes_checked[camera], true) {
                let size = frame.image.dimensions();
                let name = format!("camera {camera} of the recording");
                let checks = (|| -> Result<()> {
                    if let (0, Some(t)) = (camera, &tactile) {
                        t.check_size(&name, size, SizeFix::Recording)?;
                    }
                    if let Some(s) = &stereo {
                        s.check_size(&name, camera == 0, size, SizeFix::Recording)?;
                    }
                    Ok(())
                })();
                checks?;
            }
            recorder.send(Item::Frame {
                camera,
                info: frame.info.clone(),
                image: frame.image.clone(),
            });
            if let Some(job) = pipeline.route(camera, frame.into_labelled()) {
                jobs.push(job);
                if jobs.len() >= BATCH && !flush(&mut jobs, &mut pipeline, dropped)? {
                    stdout_open = false;
                    return Ok(ControlFlow::Break(()));
                }
            }
            Ok(ControlFlow::Continue(()))
        },
    );
    let (_, truncated) = read.map_err(|e| naming_file(e, "processing", &a.recording))?;
    if stdout_open {
        flush(&mut jobs, &mut pipeline, dropped)?;
    }
    progress.finish_and_clear();
    if let Some(why) = truncated {
        eprintln!("warning: {}: {why}", a.recording.display());
    }
    let summary = recorder.finish()?;
    report.finish(&pipeline);
    let unused = pipeline.unrouted();
    if unused.0 > 0 {
        eprintln!(
            "note: {} dx/dy pairs not reconstructed: no tactile model (the recording holds \
             none; give --model FILE)",
            unused.0
        );
    }
    if unused.1 > 0 {
        eprintln!(
            "note: {} stereo pairs not matched: no stereo calibration (the recording holds \
             none; give --calib FILE)",
            unused.1
        );
    }
    eprintln!("frames: {dropped} missing from the recording (camera sequence gaps)");
    if let Some(path) = &summary.path {
        eprintln!(
            "wrote {} ({:.1} MiB, {} messages)",
            path.display(),
            summary.bytes as f64 / (1 << 20) as f64,
            summary.messages.values().sum::<u64>()
        );
    }
    if let Some((done, len)) = interrupted_at {
        let output = if a.mcap.is_some() {
            ": the output holds the pairs read until then, and is a complete file"
        } else {
            ""
        };
        bail!(
            "interrupted after {:.0}% of {} ({done} of {len} bytes read){output}",
            100.0 * done as f64 / len.max(1) as f64,
            a.recording.display()
        );
    }
    Ok(())
}

/// LED phases, clock states and warnings go to the output as they were.
fn pass_through(recorder: &Recorder, topic: &str, data: &[u8], log_time_ns: u64, origin_ns: u64) {
    let item = match topic {
        topics::LOG => foxglove::messages::Log::decode(data)
            .ok()
            .map(|log| Item::Warning {
                at_us: log_time_ns.saturating_sub(origin_ns) as f64 / 1000.0,
                message: log.message,
            }),
        topics::LED_PHASE => serde_json::from_slice::<PhaseInfo>(data)
            .ok()
            .map(Item::Phase),
        topics::CLOCK => serde_json::from_slice::<ClockInfo>(data)
            .ok()
            .map(Item::Clock),
        _ => None,
    };
    if let Some(item) = item {
        recorder.send(item);
    }
}

/// The stages' setups: the options first, then what the recording holds.
fn setups(
    a: &Args,
    header: &RecordingHeader,
) -> Result<(Option<TactileSetup>, Option<StereoSetup>)> {
    let file = a.recording.display();
    let recorded = header.metadata.get("tactile_settings");
    let recorded_kind = recorded
        .and_then(|m| m.get("model_kind"))
        .map(|k| {
            k.parse()
                .map_err(|e| anyhow::anyhow!("{file}: metadata `tactile_settings`: {e}"))
        })
        .transpose()?;
    let kind = a.stages.model_kind.or(recorded_kind).unwrap_or_default();
    // Accepted when asked, or when the run that made the recording accepted it.
    let static_ambient = a.stages.static_ambient
        || recorded
            .and_then(|m| m.get("static_ambient"))
            .is_some_and(|v| v == "true");
    // As asked; else as the run that made the recording had it; on by default (a
    // recording without the setting), as `reconstruct`.
    let past_reach = a.past_reach
        || !a.stages.no_past_reach
            && recorded
                .and_then(|m| m.get("past_reach"))
                .is_none_or(|v| v != "false");
    let tactile = match (
        &a.stages.model,
        header.attachments.get(topics::MODEL_ATTACHMENT),
    ) {
        (Some(path), _) => Some(TactileSetup {
            model: TactileModel::load(path)?,
            references: None,
            kind,
            static_ambient,
            past_reach,
        }),
        (None, Some(json)) => {
            let name = format!("{file} attachment {}", topics::MODEL_ATTACHMENT);
            let references = match (
                header.attachments.get(REFERENCE_DX),
                header.attachments.get(REFERENCE_DY),
            ) {
                (Some(dx), Some(dy)) => Some((
                    from_png(&format!("{file} attachment {REFERENCE_DX}"), dx)?,
                    from_png(&format!("{file} attachment {REFERENCE_DY}"), dy)?,
                )),
                _ => None,
            };
            Some(TactileSetup {
                model: TactileModel::from_json(&name, json)?,
                references,
                kind,
                static_ambient,
                past_reach,
            })
        }
        (None, None) => None,
    };
    let settings =
        stereo_settings(header.metadata.get(META_STEREO)).with_context(|| format!("{file}"))?;
    let calib = if !a.stages.calib.is_empty() {
        Some(crate::stages::load_calibration(
            &a.stages.calib,
            a.stages.units,
        )?)
    } else {
        header
            .attachments
            .get(topics::CALIBRATION_ATTACHMENT)
            .map(|yaml| {
                StereoCalibration::from_opencv_yaml(
                    &format!("{file} attachment {}", topics::CALIBRATION_ATTACHMENT),
                    &String::from_utf8_lossy(yaml),
                )
            })
            .transpose()?
    };
    let config = settings.config()?;
    let stereo = calib.map(|calib| StereoSetup { calib, config });
    Ok((tactile, stereo))
}
