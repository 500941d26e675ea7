//! `stereotac run`: the sensor and one or two cameras in, time-aligned depth out, live.
//! Every frame is labelled with its LED phase; camera 0's dx/dy pairs go to the tactile
//! stage, dark frames of cameras 0 and 1 to the stereo stage. `--jsonl` prints one line
//! per tactile pair for a control loop, `--mcap` records everything, `--foxglove` serves
//! a live view. Ctrl-C, SIGTERM and SIGHUP finish the recording properly.

use std::path::PathBuf;

use anyhow::{Result, bail};
use stereotac::frames::capture::LabelledFrame;
use stereotac::live::runner::{self, Hooks, Stopped, Until};
use stereotac::live::{Output, Pipeline, check_ambient, stages_of};

use crate::args::{PipelineArgs, SequenceArgs};
use crate::cameras::CameraArgs;
use crate::console::interrupt_flag;
use crate::live_report::Report;
use crate::live_session::{self, Outputs, print_recorded};
use crate::progress::builtin_calibration;
use crate::sensor_args::DeviceArgs;
use crate::stages::{SizeFix, StageArgs, StereoSetup, TactileSetup};

/// `stereotac run`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub cameras: CameraArgs,
    /// Sequence settings: gradient (tactile), vision (stereo) or interleaved (both).
    #[command(flatten)]
    pub sequence: SequenceArgs,
    /// Tactile model and stereo calibration. With --sim and simulated cameras, built-in
    /// ones are used when none is given.
    #[command(flatten)]
    pub stages: StageArgs,
    /// Stereo matching settings.
    #[command(flatten)]
    pub pipeline: PipelineArgs,
    /// Record everything to this MCAP file (new; opens in Foxglove): raw frames, LED
    /// phases, clock sync, depth, contact, point clouds, model and calibration.
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Serve a live view for Foxglove (open ws://ADDR in Foxglove's "Open connection").
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<String>,
    /// One JSON object per reconstructed tactile pair on stdout: sequence, phase,
    /// exposure ends (host µs), contact, area mm², centroid mm, max depth mm, volume mm³,
    /// time per stage ms, latency ms, frames dropped so far.
    #[arg(long)]
    pub jsonl: bool,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// The stages' setups, loaded before the sensor is touched (a bad file is refused
/// first, and the clock sync is not left unpolled while a built-in model calibrates).
fn setups(a: &Args) -> Result<(Option<TactileSetup>, Option<StereoSetup>)> {
    let (gradients, dark) = stages_of(a.sequence.mode.into());
    let all_sim = a.device.sim && a.cameras.cameras.iter().all(|c| c == "sim");
    let tactile = if gradients {
        let setup = match &a.stages.model {
            Some(path) => TactileSetup {
                model: stereotac::tactile::model::TactileModel::load(path)?,
                references: None,
                kind: a.stages.model_kind.unwrap_or_default(),
                static_ambient: a.stages.static_ambient,
                past_reach: !a.stages.no_past_reach,
            },
            None if all_sim => {
                let (calibration, references) = builtin_calibration(
                    &a.cameras.sim_optics(),
                    Some("give --model FILE to use your own"),
                )?;
                TactileSetup {
                    model: calibration.model,
                    references: Some(references),
                    kind: a.stages.model_kind.unwrap_or_default(),
                    static_ambient: a.stages.static_ambient,
                    past_reach: !a.stages.no_past_reach,
                }
            }
            None => bail!(
                "--mode {:?} reconstructs tactile depth: give --model FILE (from `stereotac \
                 calibrate`); only --sim with simulated cameras has a built-in one",
                a.sequence.mode
            ),
        };
        check_ambient(&setup.model, a.sequence.mode.into(), setup.static_ambient).map_err(|e| {
            anyhow::anyhow!(
                "{e}: use --mode interleaved, a model calibrated without LEDs-off frames \
                 (presses recorded in gradient mode, or no NAME_dark.png files), or pass \
                 --static-ambient to remove the ambient light measured at calibration \
                 instead (wrong once the room's light changes)"
            )
        })?;
        Some(setup.round_trip()?)
    } else {
        if a.stages.model.is_some() {
            bail!("--model needs dx/dy phases: use --mode gradient or --mode interleaved");
        }
        None
    };
    let two = a.cameras.cameras.len() >= 2;
    let stereo = if dark && two {
        let calib = if !a.stages.calib.is_empty() {
            crate::stages::load_calibration(&a.stages.calib, a.stages.units)?
        } else if let (true, Some(sim)) = (a.device.sim, a.cameras.sim_stereo()) {
            sim.calibration()
        } else {
            bail!(
                "two cameras in --mode {:?} give stereo depth: give --calib stereo.yaml (or \
                 --calib left.yaml --calib right.yaml); only --sim with simulated cameras has \
                 a built-in one",
                a.sequence.mode
            );
        };
        Some(
            StereoSetup {
                calib,
                config: a.pipeline.config()?,
            }
            .round_trip()?,
        )
    } else {
        if !a.stages.calib.is_empty() {
            bail!(
                "--calib needs two cameras and dark phases: give --camera twice and --mode \
                 vision or --mode interleaved"
            );
        }
        None
    };
    if tactile.is_none() && stereo.is_none() && a.mcap.is_none() && a.foxglove.is_none() {
        bail!(
            "nothing to do: --mode {:?} with {} camera(s) gives neither tactile nor stereo \
             depth; use --mode gradient or interleaved (tactile), two cameras with --mode \
             vision or interleaved (stereo), or record with --mcap",
            a.sequence.mode,
            a.cameras.cameras.len()
        );
    }
    Ok((tactile, stereo))
}

pub fn run(a: Args) -> Result<()> {
    let stop = interrupt_flag()?;
    a.cameras.check()?;
    if a.cameras.cameras.len() > 4 {
        bail!("at most 4 cameras ({} given)", a.cameras.cameras.len());
    }
    // Said before a built-in model calibrates (~10 s), not after: the recorder would
    // refuse the file then anyway.
    if let Some(path) = a
        .mcap
        .as_ref()
        .filter(|p| std::fs::symlink_metadata(p).is_ok())
    {
        return Err(stereotac::recording::RecordingError::Exists(path.clone()).into());
    }
    let (tactile, stereo) = setups(&a)?;
    let live = live_session::start(
        "run",
        &a.device,
        &a.cameras,
        &a.sequence,
        Outputs {
            mcap: a.mcap.clone(),
            foxglove: a.foxglove.as_deref(),
        },
        |sources| {
            // Refused before anything runs: a model or calibration of another size.
            for (camera, source) in sources.iter().enumerate() {
                // A camera that cannot tell before its first frame is checked on it.
                if let Some(size) = source.frame_size() {
                    let name = format!("camera {camera} ({})", a.cameras.cameras[camera]);
                    check_size(camera, &name, size, tactile.as_ref(), stereo.as_ref())?;
                }
            }
            Ok(())
        },
    )?;
    // The model and calibration go into the recording, and the stages are set up;
    // a failure there leaves no header-only recording behind.
    let stages = (|| -> Result<_> {
        if let Some(t) = &tactile {
            t.record(&live.recorder)?;
        }
        if let Some(s) = &stereo {
            s.record(&live.recorder)?;
        }
        let stamp = |i: usize| live.session.captures()[i].stamp_ref();
        let tactile_stage = tactile.as_ref().map(|t| t.stage(stamp(0))).transpose()?;
        let stereo_stage = stereo
            .as_ref()
            .map(|s| s.stage([stamp(0), stamp(1)]))
            .transpose()?;
        Ok((tactile_stage, stereo_stage))
    })();
    let (tactile_stage, stereo_stage) = match stages {
        Ok(stages) => stages,
        Err(e) => {
            live.abandon();
            return Err(e);
        }
    };
    let mut pipeline = Pipeline::new(tactile_stage, stereo_stage);
    let mut hooks = RunHooks {
        report: Report::new(a.jsonl),
        sizes_checked: vec![false; a.cameras.cameras.len()],
        cameras: &a.cameras.cameras,
        tactile: tactile.as_ref(),
        stereo: stereo.as_ref(),
    };
    let (mut live, end_us) = live.start_sequence(&a.sequence)?;
    let sensor = &mut live.opened.sensor;
    let until = Until {
        flag: &stop,
        end_us,
    };
    let stopped = runner::run(
        &mut live.session,
        sensor,
        &live.recorder,
        &mut pipeline,
        until,
        &mut hooks,
    );
    if stopped == Stopped::Caller {
        eprintln!("stdout closed: stopped");
    }
    hooks.report.finish(&pipeline);
    live.print_cameras();
    print_recorded(&live.recorder.finish()?);
    match stopped {
        Stopped::Recorder(e) => bail!("recording failed: {e}"),
        Stopped::Failed(e) => {
            bail!("stopped: {e} (everything captured before is processed and recorded)")
        }
        _ => {}
    }
    Ok(())
}

/// What `run` does with each frame and output.
struct RunHooks<'a> {
    report: Report,
    sizes_checked: Vec<bool>,
    cameras: &'a [String],
    tactile: Option<&'a TactileSetup>,
    stereo: Option<&'a StereoSetup>,
}

impl Hooks for RunHooks<'_> {
    type Error = anyhow::Error;

    /// The first frame of each camera: refuse a model or calibration of another size.
    fn frame(&mut self, camera: usize, frame: &LabelledFrame) -> Result<()> {
        if std::mem::replace(&mut self.sizes_checked[camera], true) {
            return Ok(());
        }
        let name = format!("camera {camera} ({})", self.cameras[camera]);
        let size = frame.frame.image.dimensions();
        check_size(camera, &name, size, self.tactile, self.stereo)
    }

    fn output(&mut self, output: &Output) -> Result<bool> {
        self.report.print(output)
    }

    fn warning(&mut self, message: String) {
        eprintln!("warning: {message}");
    }
}

/// Refuses a tactile model (camera 0) or a stereo calibration (cameras 0 and 1) of
/// another frame size than camera `camera`'s.
fn check_size(
    camera: usize,
    name: &str,
    size: (u32, u32),
    tactile: Option<&TactileSetup>,
    stereo: Option<&StereoSetup>,
) -> Result<()> {
    if let (0, Some(t)) = (camera, tactile) {
        t.check_size(name, size, SizeFix::Camera)?;
    }
    if let (0 | 1, Some(s)) = (camera, stereo) {
        s.check_size(name, camera == 0, size, SizeFix::Camera)?;
    }
    Ok(())
}
