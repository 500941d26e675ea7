//! The reconstruction pipeline for one dx/dy frame pair: colour filter and contact
//! detection, gradient model on the touched pixels only, sanitising, Poisson integration
//! per region of interest, depth in millimetres.
//!
//! Depth is zero outside the imprint (the touched pixels and the holes they enclose) and
//! measured from the ring of skin around it.
//!
//! Work is proportional to contact area: a frame without contact stops after the coarse
//! detection grid; with contact, only the padded regions around contacts are normalised,
//! only their touched pixels go through the model, and only the regions are integrated.

use std::sync::Arc;
use std::time::Instant;

use image::RgbImage;
use serde::Serialize;

use super::ambient::{
    AmbientSource, MAX_BRIGHTER_FRACTION, PhaseFrames, brighter_fraction, subtract_into, subtracted,
};
use super::camera_curve::CameraCurve;
use super::colour::Reference;
use super::contact::{self, References, Roi};
use super::features::{Features, Inputs};
use super::model::photometric::Curves;
use super::model::{GainPlanes, ModelKind, PhotometricModel, TactileModel, light, validate};
use super::past_reach::{Reach, ReachLimits};
use super::phase_check::{self, PhaseImageError};
use super::poisson::{PoissonError, PoissonSolver, SolverKind};
use super::quiet::{QuietBlocks, Verdict};
use super::raw_glance::RawGlance;
use super::reference_check;
use super::sanitize::{DEFAULT_MAX_SLOPE, sanitize};
use super::unread::UnreadFill;
use crate::grid::Grid;
use crate::timing::ms_between as ms;

/// Why a frame pair could not be reconstructed.
#[derive(Debug, thiserror::Error)]
pub enum ReconstructError {
    /// dx and dy differ in size.
    #[error("dx is {dx:?} but dy is {dy:?}: both phase images must have the same size")]
    PairSize {
        /// dx `(width, height)`.
        dx: (u32, u32),
        /// dy `(width, height)`.
        dy: (u32, u32),
    },
    /// Frames, references and model disagree on size.
    #[error("{what} is {got:?} but the model was calibrated at {want:?}")]
    ModelSize {
        /// Which input.
        what: &'static str,
        /// Its size.
        got: (u32, u32),
        /// The model's size.
        want: (u32, u32),
    },
    /// Integration failed (cannot happen after sanitising; kept typed, never a panic).
    #[error("integration failed: {0}")]
    Poisson(#[from] PoissonError),
    /// The reference frames do not look like this sensor's dx and dy phases.
    #[error(transparent)]
    References(#[from] PhaseImageError),
    /// Most of the frame reads as contact, and the pair does not look like this sensor's
    /// dx and dy phases (given the wrong way round, or not lit by the strips).
    #[error(transparent)]
    FramePair(PhaseImageError),
    /// The model has a field that cannot be right (see [`super::model::validate`]).
    #[error("the model's `{field}`: {why}; recalibrate, or restore the model file")]
    InvalidModel {
        /// The field.
        field: String,
        /// What is wrong with it.
        why: String,
    },
    /// A LEDs-off frame brighter than the lit frames it goes with.
    #[error(
        "the {what} frame is brighter than the lit frames in {percent:.0}% of the frame: \
         the LEDs only add light, so it shows other light (another exposure or another \
         camera's view); give the LEDs-off frame taken with them"
    )]
    DarkFrame {
        /// Which frame.
        what: &'static str,
        /// Share of the frame where it is brighter (%).
        percent: f64,
    },
    /// The depth found is deeper (or higher) than the skin is thick: no press makes that,
    /// so the frames do not fit the model. Nothing of this pair is kept.
    #[error(
        "depth {depth_mm:.2} mm at pixel ({x}, {y}) is beyond the skin's thickness \
         ({skin_mm} mm, the model's `skin_thickness_mm`): nothing presses deeper than the \
         skin, so these frames do not fit this model (another sensor, other lighting, \
         frames of another phase, mirrored or turned frames, red and blue swapped as BGR \
         files are); if the skin is thicker, recalibrate with \
         --skin-thickness-mm"
    )]
    DepthBeyondSkin {
        /// The depth (mm; negative: raised).
        depth_mm: f32,
        /// Pixel column.
        x: usize,
        /// Pixel row.
        y: usize,
        /// The model's skin thickness (mm).
        skin_mm: f64,
    },
    /// The depth has a non-finite value (a bug: the slopes are sanitised before they are
    /// integrated, so this is kept typed, never written).
    #[error("depth at pixel ({x}, {y}) is {value}: not a depth (a bug: please report it)")]
    NonFiniteDepth {
        /// The value.
        value: f32,
        /// Pixel column.
        x: usize,
        /// Pixel row.
        y: usize,
    },
    /// Most of one phase's frame shows no usable LED light: not a lit dx/dy pair, so its
    /// depth (or "no contact") would mean nothing (see [`Reconstruction::require_lit`]).
    #[error(
        "{percent:.0}% of the {phase} frame shows no usable LED light (black, white, \
         overexposed, or taken with the LEDs off): not a lit dx/dy pair; give the {phase} \
         frame its strips lit"
    )]
    Unlit {
        /// Which frame: "dx" or "dy".
        phase: &'static str,
        /// Share of that frame without usable LED light (%).
        percent: f32,
    },
    /// Most of the frame departs from the reference frames, and as a change of light does
    /// (both strips of a phase brighter or darker alike), not as slopes do.
    #[error(
        "{percent:.0}% of the frame departs from the reference frames (flat skin), and both \
         strips of a phase alike, as a change of light does, not a press: the light changed \
         since they were taken (exposure, gain, LED brightness); give reference frames taken \
         now (--ref-dx/--ref-dy) or recalibrate"
    )]
    LightChanged {
        /// Share of the frame read as contact (%).
        percent: f32,
    },
    /// Reference frames that show a press the calibration's references did not: every
    /// frame read against them would show it as a phantom imprint.
    #[error(
        "the reference frames show a press near pixel ({x}, {y}) (a region of about \
         {width}x{height} px) that the model's background (the calibration's references) \
         does not: something touched the skin while they were taken, and every frame \
         read against them would show it as an imprint; take them again with nothing \
         touching the skin, or read without reference frames (the model's background)"
    )]
    ReferencesShowPress {
        /// Centre column of the region.
        x: usize,
        /// Centre row of the region.
        y: usize,
        /// Region width (px, with the detection's margin).
        width: usize,
        /// Region height (px, with the detection's margin).
        height: usize,
    },
    /// The model's stored ambient light does not cover its own frame size.
    #[error(
        "the model's ambient estimate ({blocks:?} blocks) does not cover its {width}x{height} \
         frames: the model file was edited or damaged; recalibrate"
    )]
    AmbientEstimate {
        /// Blocks across and down.
        blocks: (usize, usize),
        /// Model frame width.
        width: usize,
        /// Model frame height.
        height: usize,
    },
}

/// Milliseconds spent in each stage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct StageTimings {
    /// Coarse contact detection over the frame.
    pub detect_ms: f64,
    /// Colour normalisation and contact mask inside the regions.
    pub colour_ms: f64,
    /// Gradient model on touched pixels.
    pub model_ms: f64,
    /// Sanitising and Poisson integration.
    pub solve_ms: f64,
    /// Everything, including the output depth map.
    pub total_ms: f64,
}

/// What a reconstruction says when a contact had no skin at rest around it
/// ([`Reconstruction::no_skin_at_rest`]).
pub const NO_SKIN_AT_REST: &str = "the contact fills its region with no skin at rest around \
    it, so its depth has no zero (it is measured from the frame's border): is the skin \
    covered whole, or has the room's light changed since the reference frames were taken \
    (LEDs-off frames remove it: interleaved mode)?";

/// The result for one frame pair.
#[derive(Debug, Clone)]
pub struct Reconstruction {
    /// Depth in mm, positive where pressed in, 0 outside the regions of interest. Shared:
    /// every reading without contact from one reconstructor holds the same zeroed map
    /// (made once, not a 1.2 MB fill per pair at 640×480), and the reconstructor keeps a
    /// contact reading's maps to write the next contact reading into once this one is
    /// dropped; [`Arc::make_mut`] or [`Arc::unwrap_or_clone`] give a copy to change.
    pub depth_mm: Arc<Grid<f32>>,
    /// Touched pixels (the dilated contact mask), full frame; shared as `depth_mm`.
    pub contact_mask: Arc<Grid<bool>>,
    /// Regions integrated.
    pub regions: Vec<Roi>,
    /// Phase values of touched pixels the colour filter rejected (a pixel counts once
    /// per phase).
    pub rejected_pixels: usize,
    /// Slopes replaced or clamped by the sanitiser.
    pub sanitized_slopes: usize,
    /// Touched pixels whose slopes (the lookup table's or the perceptron's) reached the
    /// calibration's limit and were read by the light model too
    /// ([`super::past_reach`]; 0 when that is off).
    pub past_reach_pixels: usize,
    /// Per phase (dx, dy), the fraction of the frame where the colour filter rejected it;
    /// above [`phase_check::MIN_LIT_FRACTION`]'s complement in either, the pair is not a
    /// lit dx/dy pair and its depth or "no contact" means nothing ([`Self::unlit`]).
    pub unlit_fraction: [f32; 2],
    /// Which ambient light was removed.
    pub ambient: AmbientSource,
    /// The largest share of a region's slopes that its solved surface does not explain
    /// ([`super::integrable`]; 0 without contact). Above
    /// [`super::integrable::MAX_UNEXPLAINED`] the slopes are not one surface's
    /// ([`Self::not_one_surface`]).
    pub unexplained_share: f32,
    /// An imprint filled its whole region, with no skin at rest around it to measure its
    /// depth from (the contact covers the skin, or light that changed since the
    /// references were taken reads as contact everywhere): its depth has no zero.
    pub no_skin_at_rest: bool,
    /// Stage timings.
    pub timings: StageTimings,
}

impl ReconstructError {
    /// `true` when only this frame pair is refused (its result cannot be right), and the
    /// next pair may well be fine: live and batch runs warn and go on.
    pub fn refuses_this_pair_only(&self) -> bool {
        matches!(
            self,
            Self::DepthBeyondSkin { .. }
                | Self::NonFiniteDepth { .. }
                | Self::FramePair(_)
                | Self::LightChanged { .. }
                | Self::Unlit { .. }
        )
    }
}

impl Reconstruction {
    /// `true` when nothing touched the skin.
    pub fn no_contact(&self) -> bool {
        self.regions.is_empty()
    }

    /// `true` when a region's slopes are not the gradient of one surface (more than
    /// [`super::integrable::MAX_UNEXPLAINED`] of them unexplained): dx and dy taken at
    /// different moments. The depth is then not reliable.
    pub fn not_one_surface(&self) -> bool {
        super::integrable::not_one_surface(self.unexplained_share)
    }

    /// What to tell the reader of the depth: slopes that are not one surface's
    /// ([`Self::surface_warning`]), an imprint with no skin at rest around it
    /// ([`Self::no_skin_at_rest`]).
    pub fn warnings(&self) -> Vec<String> {
        let mut out: Vec<String> = self.surface_warning().into_iter().collect();
        if self.no_skin_at_rest {
            out.push(NO_SKIN_AT_REST.to_string());
        }
        out
    }

    /// What to tell the reader of the depth when [`Self::not_one_surface`].
    pub fn surface_warning(&self) -> Option<String> {
        super::integrable::surface_warning(self.unexplained_share)
    }

    /// `true` when most of the frame shows no usable LED light (black, white, saturated
    /// or unlit frames): the result says nothing about contact.
    pub fn unlit(&self) -> bool {
        self.unlit_phase().is_some()
    }

    /// The phase ("dx" or "dy") whose frame shows no usable LED light over most of it,
    /// the worse of the two when both do.
    pub fn unlit_phase(&self) -> Option<&'static str> {
        let [dx, dy] = self.unlit_fraction;
        let worse = if dy > dx { ("dy", dy) } else { ("dx", dx) };
        (worse.1 > 1.0 - phase_check::MIN_LIT_FRACTION).then_some(worse.0)
    }

    /// The reconstruction, or [`ReconstructError::Unlit`] when it says nothing about
    /// contact ([`Self::unlit`]): for callers that hand one result on (files, Python).
    pub fn require_lit(self) -> Result<Self, ReconstructError> {
        if let Some(phase) = self.unlit_phase() {
            let share = self.unlit_fraction[usize::from(phase == "dy")];
            return Err(ReconstructError::Unlit {
                phase,
                percent: share * 100.0,
            });
        }
        Ok(self)
    }
}

/// Where the light model reads past the reach of the calibration's slopes: with the
/// lookup table (`lut_gains`: its gains made) or the perceptron (`kind`), and light
/// models in the file; the limits are the table's (both models were fitted on the same
/// presses).
fn reach_limits_of(model: &TactileModel, kind: ModelKind, lut_gains: bool) -> Option<ReachLimits> {
    let reads = lut_gains || kind == ModelKind::Mlp;
    match (reads, &model.dx.light, &model.dy.light) {
        (true, Some(_), Some(_)) => ReachLimits::of([&model.dx.lut, &model.dy.lut]),
        _ => None,
    }
}

/// The first look at pairs as they came for `model` (whose ambient estimate at full size
/// is `ambient`), when it undoes a curve or removes ambient light before detection.
fn raw_glance_of(model: &TactileModel, ambient: Option<&RgbImage>) -> Option<Arc<RawGlance>> {
    RawGlance::new(
        model.camera_curve.as_ref(),
        ambient,
        model.contact.coarse_step,
    )
    .map(Arc::new)
}

/// Share of the frame's blocks in contact above which the pair's phases are checked.
const LARGE_CONTACT_FRACTION: f32 = 0.5;

/// Reusable reconstruction state: model, references, solver plans and buffers.
pub struct Reconstructor {
    model: TactileModel,
    kind: ModelKind,
    solver_kind: SolverKind,
    refs: References,
    block_refs: References,
    /// Budgets that tell a pair at rest from whole-number sums ([`QuietBlocks`]); `None`
    /// without reference frames or for blocks other than 4×4 px.
    quiet: Option<Arc<QuietBlocks>>,
    solver: PoissonSolver<f32>,
    max_slope: f32,
    /// The model's ambient estimate at full resolution (models calibrated on LED light).
    ambient: Option<RgbImage>,
    /// Model features and their pixel in the region, per axis.
    features: Features,
    /// Fills the slopes the colour filter could not read.
    unread_fill: UnreadFill,
    /// The lookup table's position gain at every pixel, per axis (LUT only: computed
    /// once, so the model does not blend it per pixel).
    lut_gains: Option<Arc<[GainPlanes; 2]>>,
    /// The strips' side light `κ` at every pixel (LUT only, when the model measured it;
    /// [`side_light`](super::model::side_light)).
    lut_side: Option<Arc<Vec<[f32; 2]>>>,
    /// Where the light model reads the model's slopes too (the table or the perceptron,
    /// with light models: made once from the tables; `None` when off).
    reach_limits: Option<ReachLimits>,
    slopes: Vec<f32>,
    /// The photometric model's four colours of each touched pixel.
    joint_colours: Vec<[f32; 4]>,
    /// The photometric model's response curves, tabled once (photometric only).
    photometric_curves: Option<Arc<Curves>>,
    /// LED light of the current pair (models calibrated on LED light).
    led: [RgbImage; 2],
    /// The camera's curve undone, value by value (models that measured one).
    curve_table: Option<Arc<[u8; 256]>>,
    /// The current pair's dx, dy and LEDs-off frames with the curve undone.
    linear: [RgbImage; 3],
    /// A first look at each pair as it came, for models that undo a curve or remove
    /// ambient light before detection (`None`: none, or switched off).
    raw_glance: Option<Arc<RawGlance>>,
    /// The zeroed depth map and mask every reading without contact holds.
    flat: FlatMaps,
    /// The last contact reading's maps and regions, made again for the next contact
    /// reading when its caller has let them go ([`ReusedMaps`]).
    last: Option<ReusedMaps>,
}

/// A frame's depth map and contact mask with nothing in them, shared by the readings
/// without contact ([`Reconstruction::depth_mm`]).
#[derive(Debug, Clone)]
struct FlatMaps {
    depth: Arc<Grid<f32>>,
    mask: Arc<Grid<bool>>,
}

impl FlatMaps {
    fn new(width: usize, height: usize) -> Self {
        Self {
            depth: Arc::new(Grid::filled(width, height, 0.0)),
            mask: Arc::new(Grid::filled(width, height, false)),
        }
    }
}

/// A contact reading's depth map and contact mask, kept after it is handed back: once
/// its caller has dropped the reading (the reconstructor holds the only reference), the
/// next contact reading takes the same maps with only `regions` zeroed again (a region is
/// the only part of them a reading writes), instead of a fresh 1.5 MB fill at 640×480.
#[derive(Debug)]
struct ReusedMaps {
    maps: FlatMaps,
    regions: Vec<Roi>,
}

impl ReusedMaps {
    /// The maps, zeroed, if nobody else holds them any more; `None` otherwise (the
    /// caller kept the reading, or a part of it).
    fn take_zeroed(mut self) -> Option<FlatMaps> {
        let depth = Arc::get_mut(&mut self.maps.depth)?;
        let mask = Arc::get_mut(&mut self.maps.mask)?;
        for roi in &self.regions {
            for y in roi.y..roi.y + roi.height {
                depth.row_mut(y)[roi.x..roi.x + roi.width].fill(0.0);
                mask.row_mut(y)[roi.x..roi.x + roi.width].fill(false);
            }
        }
        Some(self.maps)
    }
}

impl Reconstructor {
    /// Another reconstructor with the same model, references and settings, and its own
    /// solver plans and buffers (one per worker thread: results are identical).
    pub fn fresh(&self) -> Self {
        Self {
            model: self.model.clone(),
            kind: self.kind,
            solver_kind: self.solver_kind,
            refs: self.refs.clone(),
            block_refs: self.block_refs.clone(),
            quiet: self.quiet.clone(),
            solver: PoissonSolver::new(),
            max_slope: self.max_slope,
            ambient: self.ambient.clone(),
            features: Default::default(),
            unread_fill: UnreadFill::default(),
            lut_gains: self.lut_gains.clone(),
            lut_side: self.lut_side.clone(),
            reach_limits: self.reach_limits,
            slopes: Vec::new(),
            joint_colours: Vec::new(),
            photometric_curves: self.photometric_curves.clone(),
            led: Default::default(),
            curve_table: self.curve_table.clone(),
            linear: Default::default(),
            raw_glance: self.raw_glance.clone(),
            flat: self.flat.clone(),
            last: None,
        }
    }

    /// A reconstructor for `model` with the chosen gradient model and solver. With
    /// `references` (no-contact dx and dy frames), colours are normalised per pixel by
    /// them; without, by the model's calibrated background. A model calibrated on LED
    /// light removes the references' LEDs-off frame, or its own ambient estimate.
    pub fn new(
        model: TactileModel,
        kind: ModelKind,
        solver_kind: SolverKind,
        references: Option<PhaseFrames<'_>>,
    ) -> Result<Self, ReconstructError> {
        validate::check(&model)
            .map_err(|(field, why)| ReconstructError::InvalidModel { field, why })?;
        let want = (model.width as u32, model.height as u32);
        // The references are read with the camera's curve undone, as every frame is.
        let curve_table = model.camera_curve.map(|c| Arc::new(c.table()));
        let linear_refs = match (&curve_table, references) {
            (Some(table), Some(r)) => {
                let linear = |i: &RgbImage| {
                    let mut out = RgbImage::new(0, 0);
                    CameraCurve::linearise_into(table, i, &mut out);
                    out
                };
                Some([Some(r.dx), Some(r.dy), r.dark].map(|i| i.map(linear)))
            }
            _ => None,
        };
        let references = match &linear_refs {
            Some([Some(dx), Some(dy), dark]) => Some(PhaseFrames {
                dx,
                dy,
                dark: dark.as_ref(),
            }),
            _ => references,
        };
        let ambient = match &model.ambient {
            Some(e) if !e.fits(model.width, model.height) => {
                return Err(ReconstructError::AmbientEstimate {
                    blocks: (e.width, e.height),
                    width: model.width,
                    height: model.height,
                });
            }
            Some(e) => Some(e.image(want.0, want.1)),
            None => None,
        };
        let (refs, block_refs, quiet) = match references {
            Some(r) => {
                for (what, img) in [
                    ("reference dx", Some(r.dx)),
                    ("reference dy", Some(r.dy)),
                    ("reference dark", r.dark),
                ] {
                    if let Some(img) = img.filter(|i| i.dimensions() != want) {
                        return Err(ReconstructError::ModelSize {
                            what,
                            got: img.dimensions(),
                            want,
                        });
                    }
                }
                if let Some(dark) = r.dark.filter(|_| ambient.is_some()) {
                    let fraction = brighter_fraction(r.dx, dark).max(brighter_fraction(r.dy, dark));
                    if fraction > MAX_BRIGHTER_FRACTION {
                        return Err(ReconstructError::DarkFrame {
                            what: "reference dark",
                            percent: fraction * 100.0,
                        });
                    }
                }
                let led;
                let (dx, dy) = match (&ambient, r.dark.or(ambient.as_ref())) {
                    (Some(_), Some(dark)) => {
                        led = [subtracted(r.dx, dark), subtracted(r.dy, dark)];
                        (&led[0], &led[1])
                    }
                    _ => (r.dx, r.dy),
                };
                phase_check::check_pair(dx, dy, &model.filter, "reference frames")?;
                if let Some(r) = reference_check::press_in_references(dx, dy, &model, solver_kind) {
                    return Err(ReconstructError::ReferencesShowPress {
                        x: r.centre.0,
                        y: r.centre.1,
                        width: r.region.width,
                        height: r.region.height,
                    });
                }
                let block_refs = contact::block_references(
                    dx,
                    dy,
                    model.contact.coarse_step,
                    model.filter.unmix,
                );
                let quiet = QuietBlocks::new(dx, dy, &block_refs, &model.filter, &model.contact);
                (
                    References {
                        dx: Reference::from_image(dx, model.filter.unmix),
                        dy: Reference::from_image(dy, model.filter.unmix),
                    },
                    block_refs,
                    quiet,
                )
            }
            None => (
                model
                    .background
                    .references(model.width, model.height, model.filter.unmix),
                model.background.references_at(
                    model.width,
                    model.height,
                    model.contact.coarse_step,
                    model.filter.unmix,
                ),
                None,
            ),
        };
        let lut_gains = match kind {
            ModelKind::Lut => match (
                model.dx.lut.gain_planes(model.width, model.height),
                model.dy.lut.gain_planes(model.width, model.height),
            ) {
                (Some(dx), Some(dy)) => Some(Arc::new([dx, dy])),
                _ => None,
            },
            ModelKind::Mlp | ModelKind::Light | ModelKind::Photometric => None,
        };
        if kind == ModelKind::Photometric && model.photometric.is_none() {
            return Err(ReconstructError::InvalidModel {
                field: "photometric".into(),
                why: "absent (the model was calibrated before the photometric model \
                      existed, or its calibration left it out and said why): calibrate \
                      again, or use the lut, mlp or light model"
                    .into(),
            });
        }
        if kind == ModelKind::Light {
            for (axis, m) in [("dx", &model.dx), ("dy", &model.dy)] {
                if m.light.is_none() {
                    return Err(ReconstructError::InvalidModel {
                        field: format!("{axis}.light"),
                        why: "absent (the model was calibrated before the light model \
                              existed, or its calibration left it out and said why): \
                              calibrate again, or use the lut or mlp model"
                            .into(),
                    });
                }
            }
        }
        let lut_side = match (&lut_gains, &model.side_light) {
            (Some(_), Some(side)) => Some(Arc::new(side.planes(model.width, model.height))),
            _ => None,
        };
        let reach_limits = reach_limits_of(&model, kind, lut_gains.is_some());
        let photometric_curves = match (kind, &model.photometric) {
            (ModelKind::Photometric, Some(m)) => Some(Arc::new(m.curves())),
            _ => None,
        };
        let raw_glance = raw_glance_of(&model, ambient.as_ref());
        Ok(Self {
            flat: FlatMaps::new(model.width, model.height),
            last: None,
            raw_glance,
            photometric_curves,
            lut_gains,
            lut_side,
            reach_limits,
            model,
            kind,
            solver_kind,
            refs,
            block_refs,
            quiet: quiet.map(Arc::new),
            solver: PoissonSolver::new(),
            max_slope: DEFAULT_MAX_SLOPE,
            ambient,
            features: Default::default(),
            unread_fill: UnreadFill::default(),
            slopes: Vec::new(),
            joint_colours: Vec::new(),
            led: Default::default(),
            curve_table,
            linear: Default::default(),
        })
    }

    /// The calibrated model.
    pub fn model(&self) -> &TactileModel {
        &self.model
    }

    /// Turns the light model's reading of slopes steeper than the calibration's
    /// ([`super::past_reach`]) on (the default) or off (the model's slopes alone, as
    /// before; for a skin the light model over-reads). It can be on only with the lookup
    /// table or the perceptron and a model file that has light models; returns whether
    /// it is on now.
    pub fn set_past_reach(&mut self, on: bool) -> bool {
        self.reach_limits = if on {
            reach_limits_of(&self.model, self.kind, self.lut_gains.is_some())
        } else {
            None
        };
        self.reach_limits.is_some()
    }

    /// Whether the light model reads slopes steeper than the calibration's
    /// ([`Self::set_past_reach`]).
    pub fn reads_past_reach(&self) -> bool {
        self.reach_limits.is_some()
    }

    /// Turns the first look at each pair as the camera gave it ([`super::raw_glance`])
    /// on (the default) or off (every pair's frames undone and their ambient light
    /// subtracted before detection, as before 2026-12-02; for comparisons). It can be on
    /// only for a model that undoes a camera curve or removes ambient light; returns
    /// whether it is on now.
    pub fn set_raw_glance(&mut self, on: bool) -> bool {
        self.raw_glance = if on {
            raw_glance_of(&self.model, self.ambient.as_ref())
        } else {
            None
        };
        self.raw_glance.is_some()
    }

    /// Reconstructs one frame pair (no LEDs-off frame).
    pub fn reconstruct(
        &mut self,
        dx: &RgbImage,
        dy: &RgbImage,
    ) -> Result<Reconstruction, ReconstructError> {
        self.reconstruct_frames((dx, dy).into())
    }

    /// Reconstructs one frame pair, removing the ambient light its LEDs-off frame shows
    /// when the model was calibrated on LED light (otherwise the dark frame is unused:
    /// [`Reconstruction::ambient`] says which light was removed).
    pub fn reconstruct_frames(
        &mut self,
        frames: PhaseFrames<'_>,
    ) -> Result<Reconstruction, ReconstructError> {
        let start = Instant::now();
        let (dx, dy) = (frames.dx, frames.dy);
        if dx.dimensions() != dy.dimensions() {
            return Err(ReconstructError::PairSize {
                dx: dx.dimensions(),
                dy: dy.dimensions(),
            });
        }
        let want = (self.model.width as u32, self.model.height as u32);
        for (what, img) in [("frame", Some(dx)), ("dark frame", frames.dark)] {
            if let Some(img) = img.filter(|i| i.dimensions() != want) {
                return Err(ReconstructError::ModelSize {
                    what,
                    got: img.dimensions(),
                    want,
                });
            }
        }
        // A skin at rest is told from the frames as they came, before any pass over them.
        if let Some(glance) = &self.raw_glance {
            let (refs, filter) = (&self.block_refs, &self.model.filter);
            if let Some((detection, ambient)) =
                glance.at_rest(frames, refs, filter, &self.model.contact)
            {
                let mut out = self.reading(&detection, ambient, start);
                out.timings.total_ms = ms(start, Instant::now());
                return Ok(out);
            }
        }
        // With the camera's curve undone first, into buffers taken out for the call.
        let mut linear = std::mem::take(&mut self.linear);
        let frames = match &self.curve_table {
            Some(table) => {
                let [ldx, ldy, ldark] = &mut linear;
                CameraCurve::linearise_into(table, dx, ldx);
                CameraCurve::linearise_into(table, dy, ldy);
                if let Some(dark) = frames.dark {
                    CameraCurve::linearise_into(table, dark, ldark);
                }
                PhaseFrames {
                    dx: ldx,
                    dy: ldy,
                    dark: frames.dark.map(|_| &*ldark),
                }
            }
            None => frames,
        };
        let result = self.reconstruct_linear(frames, start);
        self.linear = linear;
        result
    }

    /// [`Self::reconstruct_frames`] on frames of linear light.
    fn reconstruct_linear(
        &mut self,
        frames: PhaseFrames<'_>,
        start: Instant,
    ) -> Result<Reconstruction, ReconstructError> {
        let (dx, dy) = (frames.dx, frames.dy);
        // Taken out for the call and put back: the reconstructor stays reusable.
        let mut led = std::mem::take(&mut self.led);
        let estimate = self.ambient.take();
        let result = match (&estimate, frames.dark) {
            (None, _) => self.reconstruct_light(dx, dy, AmbientSource::ColourFilter, start),
            (Some(estimate), dark) => {
                let [led_dx, led_dy] = &mut led;
                let mut source = AmbientSource::Calibration;
                if let Some(dark) = dark {
                    let brighter =
                        subtract_into(dx, dark, led_dx).max(subtract_into(dy, dark, led_dy));
                    source = if brighter > MAX_BRIGHTER_FRACTION {
                        AmbientSource::CalibrationDarkRefused
                    } else {
                        AmbientSource::DarkFrame
                    };
                }
                if source != AmbientSource::DarkFrame {
                    subtract_into(dx, estimate, led_dx);
                    subtract_into(dy, estimate, led_dy);
                }
                self.reconstruct_light(led_dx, led_dy, source, start)
            }
        };
        self.led = led;
        self.ambient = estimate;
        result
    }

    /// Reconstructs a pair of the light the model works on.
    fn reconstruct_light(
        &mut self,
        dx: &RgbImage,
        dy: &RgbImage,
        ambient: AmbientSource,
        start: Instant,
    ) -> Result<Reconstruction, ReconstructError> {
        let filter = self.model.filter;
        let params = self.model.contact;
        // A pair at rest is told from whole-number sums where the references allow
        // (the glance's answer, block for block: `quiet`), which also say when the glance
        // would look at every row; otherwise looked at as before.
        let refs = &self.block_refs;
        let verdict = self
            .quiet
            .as_ref()
            .map(|q| q.glance(dx, dy, refs, &filter, &params));
        let detection = match verdict {
            Some(Verdict::AtRest(detection)) => detection,
            Some(Verdict::LookAtEveryRow) => {
                contact::look_at_every_row(dx, dy, refs, &filter, &params, self.solver_kind)
            }
            Some(Verdict::CannotTell) | None => {
                contact::find_regions(dx, dy, refs, &filter, &params, self.solver_kind)
            }
        };
        // A contact over most of the frame is rare; dx and dy given the wrong way round
        // look like one everywhere. Checked only then: it costs a pass over the frame.
        let touched = detection.touched.iter().filter(|t| **t).count();
        if touched as f32 > LARGE_CONTACT_FRACTION * detection.touched.len() as f32 {
            phase_check::check_pair(dx, dy, &filter, "frame pair")
                .map_err(ReconstructError::FramePair)?;
            // Lit phases the right way round, and most of the skin departs from its
            // reference as a change of light does (both strips of a phase the same way),
            // not as slopes do (a texture pressed over the whole skin is read).
            if contact::departs_as_light_change(dx, dy, &self.block_refs, &filter, &detection) {
                return Err(ReconstructError::LightChanged {
                    percent: 100.0 * touched as f32 / detection.touched.len().max(1) as f32,
                });
            }
        }
        let mut out = self.reading(&detection, ambient, start);
        if !detection.regions.is_empty() {
            // Maps of this reading's own, to write the regions into: the last contact
            // reading's if its caller let them go, else new ones.
            let (w, h) = (self.model.width, self.model.height);
            let maps = self
                .last
                .take()
                .and_then(ReusedMaps::take_zeroed)
                .unwrap_or_else(|| FlatMaps::new(w, h));
            (out.depth_mm, out.contact_mask) = (maps.depth, maps.mask);
            for roi in &detection.regions {
                self.region(dx, dy, roi, &detection, &mut out)?;
            }
            self.last = Some(ReusedMaps {
                maps: FlatMaps {
                    depth: Arc::clone(&out.depth_mm),
                    mask: Arc::clone(&out.contact_mask),
                },
                regions: detection.regions.clone(),
            });
        }
        out.regions = detection.regions;
        out.timings.total_ms = ms(start, Instant::now());
        Ok(out)
    }

    /// A reading with nothing in it yet: flat depth and no contact (the shared zeroed
    /// maps), the detection's unlit fractions, detection's time since `start`.
    fn reading(
        &self,
        detection: &contact::Detection,
        ambient: AmbientSource,
        start: Instant,
    ) -> Reconstruction {
        Reconstruction {
            depth_mm: Arc::clone(&self.flat.depth),
            contact_mask: Arc::clone(&self.flat.mask),
            regions: Vec::new(),
            rejected_pixels: 0,
            sanitized_slopes: 0,
            past_reach_pixels: 0,
            unlit_fraction: detection.unlit_fraction,
            ambient,
            unexplained_share: 0.0,
            no_skin_at_rest: false,
            timings: StageTimings {
                detect_ms: ms(start, Instant::now()),
                ..Default::default()
            },
        }
    }

    fn region(
        &mut self,
        dx: &RgbImage,
        dy: &RgbImage,
        roi: &Roi,
        detection: &contact::Detection,
        out: &mut Reconstruction,
    ) -> Result<(), ReconstructError> {
        let t0 = Instant::now();
        let (w, h) = (self.model.width, self.model.height);
        let filter = self.model.filter;
        let params = self.model.contact;
        // Touched pixels: the touched blocks, grown to take in the faint outer slopes.
        let mask = detection.touched_pixels(roi, params.dilate_px);

        let inputs = Inputs {
            dx,
            dy,
            refs: &self.refs,
            filter: &filter,
            gains: self.lut_gains.as_deref(),
            side: self.lut_side.as_deref().map(Vec::as_slice),
            // Slopes past the table's reach are read by the light model too, when the
            // model file has one.
            reach: match (
                self.reach_limits,
                &self.model.dx.light,
                &self.model.dy.light,
            ) {
                (Some(limits), Some(x), Some(y)) => Some(Reach::new(limits, [x, y])),
                _ => None,
            },
        };
        let mut p = Grid::filled(roi.width, roi.height, 0.0f32);
        let mut q = Grid::filled(roi.width, roi.height, 0.0f32);
        let t2 = if self.lut_gains.is_some() {
            // The lookup table (its gains are made only for it) reads the colours as they
            // are made: one pass, no rows of features in between; each stage's time is
            // measured inside it.
            let (counts, times) = self.features.lut_slopes(
                &inputs,
                roi,
                &mask,
                [&self.model.dx.lut, &self.model.dy.lut],
                [p.as_mut_slice(), q.as_mut_slice()],
                self.max_slope,
            );
            out.sanitized_slopes += counts.sanitized;
            out.past_reach_pixels += counts.past_reach;
            out.rejected_pixels += self.features.rejected();
            let t2 = Instant::now();
            let overhead = ms(t0, t2) - times.colour_ms - times.model_ms;
            out.timings.colour_ms += times.colour_ms + overhead;
            out.timings.model_ms += times.model_ms;
            t2
        } else if let (ModelKind::Photometric, Some(model), Some(curves)) =
            (self.kind, &self.model.photometric, &self.photometric_curves)
        {
            // All four colours of each touched pixel at once, as they are (the feature
            // rows hold each phase divided by the other's brightness: not made here).
            let rejected = photometric_colours(&inputs, roi, &mask, &mut self.joint_colours);
            out.rejected_pixels += rejected;
            let t1 = Instant::now();
            out.timings.colour_ms += ms(t0, t1);
            photometric_slopes(
                (model, curves),
                (inputs.dx.width(), inputs.dx.height()),
                roi,
                &mask,
                &self.joint_colours,
                [p.as_mut_slice(), q.as_mut_slice()],
                &mut self.features.unread,
            );
            for grid in [&mut p, &mut q] {
                let fixed = sanitize(grid.as_mut_slice(), self.max_slope);
                out.sanitized_slopes += fixed.non_finite + fixed.clamped;
            }
            let t2 = Instant::now();
            out.timings.model_ms += ms(t1, t2);
            t2
        } else {
            // Each axis' model features of the touched pixels the colour filter accepts;
            // the others get no slope on that axis.
            self.features.collect(&inputs, roi, &mask);
            out.rejected_pixels += self.features.rejected();
            let t1 = Instant::now();
            out.timings.colour_ms += ms(t0, t1);
            if let (ModelKind::Light, Some(lx), Some(ly)) =
                (self.kind, &self.model.dx.light, &self.model.dy.light)
            {
                // Both phases at once (see `light::read_rows`); then the same bounds.
                let [fx, fy] = &self.features.axes;
                light::read_rows(
                    [lx, ly],
                    [&fx.rows, &fy.rows],
                    [&fx.targets, &fy.targets],
                    [p.as_mut_slice(), q.as_mut_slice()],
                );
                for grid in [&mut p, &mut q] {
                    let fixed = sanitize(grid.as_mut_slice(), self.max_slope);
                    out.sanitized_slopes += fixed.non_finite + fixed.clamped;
                }
            } else {
                for (axis, grid) in [(0usize, &mut p), (1, &mut q)] {
                    self.slopes.clear();
                    let features = &self.features.axes[axis];
                    self.slopes.resize(features.rows.len(), 0.0);
                    let model = if axis == 0 {
                        &self.model.dx
                    } else {
                        &self.model.dy
                    };
                    model.eval(self.kind, &features.rows, &mut self.slopes);
                    // Non-finite slopes become 0 and the rest are bounded (the grid's other
                    // pixels are 0 already).
                    let fixed = sanitize(&mut self.slopes, self.max_slope);
                    out.sanitized_slopes += fixed.non_finite + fixed.clamped;
                    let values = grid.as_mut_slice();
                    for (&k, &s) in features.targets.iter().zip(&self.slopes) {
                        values[k] = s;
                    }
                }
                // The perceptron saturates as the table does: past the calibration's
                // slopes the light model reads as well.
                if let (ModelKind::Mlp, Some(reach)) = (self.kind, &inputs.reach) {
                    let [fx, fy] = &self.features.axes;
                    out.past_reach_pixels += reach.extend_rows(
                        [&fx.rows, &fy.rows],
                        [&fx.targets, &fy.targets],
                        [p.as_mut_slice(), q.as_mut_slice()],
                        self.max_slope,
                    );
                }
            }
            let t2 = Instant::now();
            out.timings.model_ms += ms(t1, t2);
            t2
        };

        // Slopes the colour filter could not read (a saturated or unlit phase), or the
        // photometric model could not explain, are unknown, not flat: filled from their
        // neighbours.
        for (grid, unread) in [
            (&mut p, &self.features.unread[0]),
            (&mut q, &self.features.unread[1]),
        ] {
            self.unread_fill
                .fill(grid.as_mut_slice(), roi.width, unread);
        }
        let depth_px = self.solver.integrate(self.solver_kind, &p, &q)?;
        // Slopes of frames that do not belong together are no surface's: said, not
        // hidden behind the depth the solve makes of them all the same.
        let share = super::integrable::unexplained_share(&depth_px, &p, &q);
        out.unexplained_share = out.unexplained_share.max(share);
        // The imprint is the touched pixels with the holes they enclose (a flat-bottomed
        // object's plateau has no slope but is pressed in). Skin outside it is at rest:
        // its depth is zero, and the imprint's depth is measured from the ring of skin
        // just around it rather than from the region's border.
        let mut imprint = mask.clone();
        contact::fill_holes(&mut imprint, roi.width, roi.height);
        // No skin at rest around the imprint (it fills its region): its depth has no
        // zero, and is measured from the region's border (the solve's level).
        let anchor = ring_median(depth_px.as_slice(), &imprint, roi.width, roi.height)
            .unwrap_or_else(|| {
                out.no_skin_at_rest = true;
                0.0
            });
        let scale = 1.0 / self.model.px_per_mm as f32;
        // The deepest (or highest) point, to hold against the skin's thickness.
        let mut extreme = (0.0f32, 0usize, 0usize);
        // The reading's own maps (made for it: no copy).
        let depth_mm = Arc::make_mut(&mut out.depth_mm);
        let contact_mask = Arc::make_mut(&mut out.contact_mask);
        for ry in 0..roi.height {
            let y = roi.y + ry;
            let src = depth_px.row(ry);
            let inside = &imprint[ry * roi.width..(ry + 1) * roi.width];
            let dst = &mut depth_mm.row_mut(y)[roi.x..roi.x + roi.width];
            for ((d, s), &keep) in dst.iter_mut().zip(src).zip(inside) {
                *d = if keep { (s - anchor) * scale } else { 0.0 };
            }
            update_extreme(&mut extreme, dst, roi.x, y);
            let m = &mut contact_mask.row_mut(y)[roi.x..roi.x + roi.width];
            for (d, s) in m
                .iter_mut()
                .zip(&mask[ry * roi.width..(ry + 1) * roi.width])
            {
                *d |= *s;
            }
        }
        debug_assert!(roi.x + roi.width <= w && roi.y + roi.height <= h);
        let (value, x, y) = extreme;
        if !value.is_finite() {
            return Err(ReconstructError::NonFiniteDepth { value, x, y });
        }
        if f64::from(value.abs()) > self.model.skin_thickness_mm {
            return Err(ReconstructError::DepthBeyondSkin {
                depth_mm: value,
                x,
                y,
                skin_mm: self.model.skin_thickness_mm,
            });
        }
        out.timings.solve_ms += ms(t2, Instant::now());
        Ok(())
    }
}

/// The four normalised colours `[r_dx, b_dx, r_dy, b_dy]` of `mask`'s pixels (row-major
/// over `roi`) into `out`, as [`contact::colours_of`] gives them (NaN for a phase the
/// colour filter rejects); returns how many phases were rejected.
fn photometric_colours(
    inputs: &Inputs<'_>,
    roi: &Roi,
    mask: &[bool],
    out: &mut Vec<[f32; 4]>,
) -> usize {
    let w = inputs.dx.width() as usize;
    let (dx, dy) = (inputs.dx.as_raw(), inputs.dy.as_raw());
    out.clear();
    let mut rejected = 0;
    for (k, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let i = (roi.y + k / roi.width) * w + roi.x + k % roi.width;
        let at = |raw: &[u8]| [0, 1, 2].map(|c| f32::from(raw[3 * i + c]));
        let (colours, _) = contact::colours_of(inputs.refs, inputs.filter, i, at(dx), at(dy));
        rejected += usize::from(colours[0].is_nan()) + usize::from(colours[2].is_nan());
        out.push(colours);
    }
    rejected
}

/// The photometric model's slopes of `mask`'s pixels (row-major over `roi`, a frame of
/// `w × h`) into `slopes` (`[p, q]` grids of the region), from their `colours`
/// ([`photometric_colours`], in the same order). Pixels the model cannot read (a rejected
/// phase among them) make up both axes' `unread` lists (filled from their neighbours).
fn photometric_slopes(
    (model, curves): (&PhotometricModel, &Curves),
    (w, h): (u32, u32),
    roi: &Roi,
    mask: &[bool],
    colours: &[[f32; 4]],
    slopes: [&mut [f32]; 2],
    unread: &mut [Vec<usize>; 2],
) {
    debug_assert_eq!(colours.len(), mask.iter().filter(|m| **m).count());
    let (inv_w, inv_h) = (1.0 / w as f32, 1.0 / h as f32);
    let [p, q] = slopes;
    unread.iter_mut().for_each(Vec::clear);
    let touched = mask.iter().enumerate().filter(|(_, m)| **m).map(|(k, _)| k);
    for (k, &c) in touched.zip(colours) {
        let (x, y) = (roi.x + k % roi.width, roi.y + k / roi.width);
        match model.read_with(curves, c, x as f32 * inv_w, y as f32 * inv_h) {
            Some([sp, sq]) => [p[k], q[k]] = [sp, sq],
            None => unread.iter_mut().for_each(|u| u.push(k)),
        }
    }
}

/// `extreme` (`(depth, x, y)`, the largest |depth| so far, or the first value that is not
/// finite, which is kept, never replaced) updated with `row`, row `y` of depths from
/// column `x0`. Rows that hold no NaN and nothing beyond it are not searched: the bits of
/// |depth| order as the values do and a NaN's lie above infinity's, so one integer maximum
/// (in vector lanes) tells.
fn update_extreme(extreme: &mut (f32, usize, usize), row: &[f32], x0: usize, y: usize) {
    let largest = row.iter().fold(0u32, |m, d| m.max(d.abs().to_bits()));
    let beats = largest > f32::INFINITY.to_bits() || f32::from_bits(largest) > extreme.0.abs();
    if !(extreme.0.is_finite() && beats) {
        return;
    }
    for (dx, d) in row.iter().enumerate() {
        if extreme.0.is_finite() && (d.is_nan() || d.abs() > extreme.0.abs()) {
            *extreme = (*d, x0 + dx, y);
        }
    }
}

/// The median depth of the pixels next to the imprint (left, right, above or below one of
/// its pixels) but not in it: the skin at rest around it. `None` when there are none (the
/// imprint fills the region, or is empty).
fn ring_median(depth: &[f32], imprint: &[bool], w: usize, h: usize) -> Option<f32> {
    let mut ring = Vec::new();
    let mut near = vec![false; w];
    for (y, inside) in imprint.chunks_exact(w.max(1)).enumerate() {
        // Row by row: a pixel touches the imprint through its left, right, upper or
        // lower neighbour (whole-row operations that run in vector lanes).
        near.fill(false);
        if w > 1 {
            for (n, &i) in near[1..].iter_mut().zip(inside) {
                *n |= i;
            }
            for (n, &i) in near.iter_mut().zip(&inside[1..]) {
                *n |= i;
            }
        }
        for other in [y.checked_sub(1), (y + 1 < h).then_some(y + 1)]
            .into_iter()
            .flatten()
        {
            for (n, &i) in near.iter_mut().zip(&imprint[other * w..(other + 1) * w]) {
                *n |= i;
            }
        }
        let row = &depth[y * w..(y + 1) * w];
        for ((&d, &n), &i) in row.iter().zip(&near).zip(inside) {
            if n & !i {
                ring.push(d);
            }
        }
    }
    if ring.is_empty() {
        return None;
    }
    let k = ring.len() / 2;
    Some(*ring.select_nth_unstable_by(k, f32::total_cmp).1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extreme_is_the_largest_magnitude_or_the_first_non_finite() {
        let mut e = (0.0f32, 0, 0);
        update_extreme(&mut e, &[0.0, 0.5, -0.7, 0.2], 10, 3);
        assert_eq!(e, (-0.7, 12, 3));
        // A row with nothing beyond it changes nothing; a tie keeps the first.
        update_extreme(&mut e, &[0.1, 0.7, -0.3], 0, 4);
        assert_eq!(e, (-0.7, 12, 3));
        update_extreme(&mut e, &[0.9, f32::INFINITY], 0, 5);
        assert_eq!(e, (f32::INFINITY, 1, 5));
        // Not finite: kept, even against a NaN after it.
        update_extreme(&mut e, &[f32::NAN], 0, 6);
        assert_eq!(e, (f32::INFINITY, 1, 5));
        // The first NaN wins over anything after it and stays.
        let mut e = (0.3f32, 1, 1);
        update_extreme(&mut e, &[0.0, f32::NAN, 5.0, -f32::NAN], 2, 6);
        assert!(e.0.is_nan() && (e.1, e.2) == (3, 6), "{e:?}");
        update_extreme(&mut e, &[9.0, f32::NAN], 0, 7);
        assert_eq!((e.1, e.2), (3, 6));
        // An empty row changes nothing.
        let mut e = (0.25f32, 4, 4);
        update_extreme(&mut e, &[], 0, 0);
        assert_eq!(e, (0.25, 4, 4));
    }

    /// The row-wise ring equals the pixel-by-pixel definition on random imprints.
    #[test]
    fn ring_median_matches_its_definition() {
        fn direct(depth: &[f32], imprint: &[bool], w: usize, h: usize) -> Option<f32> {
            let mut ring = Vec::new();
            for y in 0..h {
                for x in 0..w {
                    let i = y * w + x;
                    let touches = (x > 0 && imprint[i - 1])
                        || (x + 1 < w && imprint[i + 1])
                        || (y > 0 && imprint[i - w])
                        || (y + 1 < h && imprint[i + w]);
                    if !imprint[i] && touches {
                        ring.push(depth[i]);
                    }
                }
            }
            ring.sort_by(f32::total_cmp);
            ring.get(ring.len() / 2).copied()
        }
        let mut rng = crate::rng::Rng::new(6);
        let mut rings = 0;
        for (w, h) in [(1, 1), (1, 6), (6, 1), (9, 7), (40, 23)] {
            for density in [0.0, 0.1, 0.5, 1.0] {
                let imprint: Vec<bool> = (0..w * h).map(|_| rng.uniform() < density).collect();
                let depth: Vec<f32> = (0..w * h).map(|_| rng.range(-1.0, 1.0) as f32).collect();
                let want = direct(&depth, &imprint, w, h);
                rings += usize::from(want.is_some());
                assert_eq!(
                    ring_median(&depth, &imprint, w, h),
                    want,
                    "{w}x{h} density {density}"
                );
            }
        }
        assert!(rings >= 8, "most cases had a ring: {rings}");
    }
}
