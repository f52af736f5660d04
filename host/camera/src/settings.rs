//! What a capture needs set on a GenICam camera, from a TOML file and flags, and what
//! the camera actually applied (read back: cameras round exposure, clamp regions, and
//! refuse what they do not have).

use std::path::Path;

use anyhow::{bail, Context, Result};
use serde::{Deserialize, Serialize};

use crate::aravis::Camera;
use crate::pixels::PixelFormat;

/// Camera settings, each optional: what is not given is left as the camera has it.
///
/// ```toml
/// pixel_format = "Mono12Packed"   # Mono8, Mono10/12/14/16, Mono10p/12p, Mono10Packed/12Packed
/// exposure_us = 20000.0
/// gain = 0.0                      # the camera's unit, usually dB
/// roi = [0, 0, 2048, 2048]        # x, y, width, height
/// binning = 1
/// trigger = "Line0"               # a TriggerSource ("Line0", "Software", ...) or "Off"
/// trigger_activation = "RisingEdge"
/// channel = "G"                   # colour sensors (Bayer formats): the LEDs' channel
/// ```
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSettings {
    /// PixelFormat.
    pub pixel_format: Option<String>,
    /// ExposureTime, µs.
    pub exposure_us: Option<f64>,
    /// Gain.
    pub gain: Option<f64>,
    /// Region of interest: x, y, width, height.
    pub roi: Option<[i32; 4]>,
    /// Binning, both directions.
    pub binning: Option<i32>,
    /// TriggerSource for FrameStart with TriggerMode On, or "Off" for free running.
    pub trigger: Option<String>,
    /// TriggerActivation ("RisingEdge", "FallingEdge", ...).
    pub trigger_activation: Option<String>,
    /// For a colour sensor's mosaic (Bayer formats): the channel to publish ("R", "G",
    /// "B"), its own pixels, one per 2 × 2 cell.
    pub channel: Option<String>,
}

impl CameraSettings {
    /// Read a TOML file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading camera settings {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("camera settings {}", path.display()))
    }

    /// These settings, with every field `over` gives replacing ours.
    pub fn overridden_by(self, over: CameraSettings) -> Self {
        Self {
            pixel_format: over.pixel_format.or(self.pixel_format),
            exposure_us: over.exposure_us.or(self.exposure_us),
            gain: over.gain.or(self.gain),
            roi: over.roi.or(self.roi),
            binning: over.binning.or(self.binning),
            trigger: over.trigger.or(self.trigger),
            trigger_activation: over.trigger_activation.or(self.trigger_activation),
            channel: over.channel.or(self.channel),
        }
    }

    /// Set them on `camera`, in the order that keeps each valid (binning and format
    /// change the sensor's size, so before the region; triggers last). Each failure
    /// names the feature and value.
    pub fn apply(&self, camera: &Camera) -> Result<()> {
        if let Some(b) = self.binning {
            camera.set_binning(b, b)?;
        }
        if let Some(f) = &self.pixel_format {
            let offered = camera.pixel_formats().unwrap_or_default();
            if !offered.is_empty() && !offered.iter().any(|o| o == f) {
                bail!(
                    "the camera has no pixel format {f}; it offers {}",
                    offered.join(", ")
                );
            }
            camera.set_pixel_format(f)?;
        }
        if let Some([x, y, w, h]) = self.roi {
            camera.set_region(x, y, w, h)?;
        }
        if let Some(us) = self.exposure_us {
            camera.set_exposure_us(us)?;
        }
        if let Some(g) = self.gain {
            if !camera.gain_available()? {
                bail!("the camera has no gain control (gain = {g} was asked)");
            }
            camera.set_gain(g)?;
        }
        match self.trigger.as_deref() {
            None => {}
            Some(off) if off.eq_ignore_ascii_case("off") => camera.clear_triggers()?,
            Some(source) => camera.set_trigger(source)?,
        }
        if let Some(a) = &self.trigger_activation {
            camera.set_string("TriggerActivation", a)?;
        }
        Ok(())
    }
}

/// The settings in force, as read back from the camera (for logs, `acquisition.json`
/// and the dataset's `[camera]` block).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AppliedSettings {
    /// Vendor.
    pub vendor: String,
    /// Model.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// PixelFormat's name.
    pub pixel_format: String,
    /// Significant bits per pixel in the published frames.
    pub bit_depth: Option<u32>,
    /// Raw colour mosaic pattern ("RGGB", ...), None for a mono sensor.
    pub bayer: Option<String>,
    /// Region of interest: x, y, width, height.
    pub roi: [i32; 4],
    /// Binning: horizontal, vertical.
    pub binning: [i32; 2],
    /// ExposureTime, µs; None where each frame has its own (an auto-exposing camera:
    /// each frame's header carries it).
    pub exposure_us: Option<f64>,
    /// The gamma that decodes the published frames to light, in the dataset's
    /// convention (`[camera] gamma`: a value v stands for full·(v/full)^gamma): 1 for
    /// raw counts; None where the camera cannot say (a lookup table is on). See
    /// [`GammaFeatures::encoding_gamma`].
    pub encoding_gamma: Option<f64>,
    /// Gain, if the camera has one.
    pub gain: Option<f64>,
    /// TriggerMode (FrameStart).
    pub trigger_mode: Option<String>,
    /// TriggerSource.
    pub trigger_source: Option<String>,
    /// TriggerActivation.
    pub trigger_activation: Option<String>,
    /// The sensor's pixel pitch, µm, if the camera reports it (SensorPixelWidth).
    pub pixel_size_um: Option<f64>,
    /// The channel published from a colour mosaic, if one is.
    pub channel: Option<String>,
    /// Width and height of the frames published.
    pub published_size: [i32; 2],
    /// Published pixels per sensor pixel, each way (2 for a mosaic's channel).
    pub published_pixel_factor: i32,
}

impl AppliedSettings {
    /// Read them from `camera`.
    pub fn read(camera: &Camera) -> Result<Self> {
        let (x, y, w, h) = camera.region()?;
        let (bx, by) = camera.binning().unwrap_or((1, 1));
        let pixel_format = camera.pixel_format()?;
        let optional_string = |f: &str| {
            camera
                .has_feature(f)
                .then(|| camera.string(f).ok())
                .flatten()
        };
        let format = pixel_format_code(&pixel_format);
        Ok(Self {
            vendor: camera.vendor().unwrap_or_default(),
            model: camera.model().unwrap_or_default(),
            serial: camera.serial().unwrap_or_default(),
            bit_depth: format.map(PixelFormat::bit_depth),
            bayer: format.and_then(PixelFormat::bayer).map(str::to_owned),
            pixel_format,
            roi: [x, y, w, h],
            binning: [bx, by],
            exposure_us: Some(camera.exposure_us()?),
            encoding_gamma: GammaFeatures::read(camera).encoding_gamma(),
            gain: camera
                .gain_available()
                .unwrap_or(false)
                .then(|| camera.gain().ok())
                .flatten(),
            trigger_mode: optional_string("TriggerMode"),
            trigger_source: optional_string("TriggerSource"),
            trigger_activation: optional_string("TriggerActivation"),
            pixel_size_um: camera
                .has_feature("SensorPixelWidth")
                .then(|| camera.float("SensorPixelWidth").ok())
                .flatten(),
            channel: None,
            published_size: [w, h],
            published_pixel_factor: 1,
        })
    }

    /// Whether each frame waits for a trigger.
    pub fn triggered(&self) -> bool {
        self.trigger_mode.as_deref() == Some("On")
    }
}

/// A camera's features that change how its pixel values follow the light (GenICam
/// SFNC names; each None where the camera does not have it).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GammaFeatures {
    /// LUTEnable: a user lookup table is applied to every pixel.
    pub lut_enable: Option<bool>,
    /// GammaEnable (Basler, FLIR): whether Gamma is applied at all.
    pub gamma_enable: Option<bool>,
    /// GammaSelector (Basler): "User" (Gamma's value) or "sRGB" (a fixed curve).
    pub gamma_selector: Option<String>,
    /// Gamma: the camera outputs full·(v/full)^Gamma (below 1 brightens the image).
    pub gamma: Option<f64>,
}

impl GammaFeatures {
    /// Read them from `camera` (a feature that cannot be read counts as absent).
    pub fn read(camera: &Camera) -> Self {
        let boolean = |f: &str| {
            camera
                .has_feature(f)
                .then(|| camera.boolean(f).ok())
                .flatten()
        };
        Self {
            lut_enable: boolean("LUTEnable"),
            gamma_enable: boolean("GammaEnable"),
            gamma_selector: camera
                .has_feature("GammaSelector")
                .then(|| camera.string("GammaSelector").ok())
                .flatten(),
            gamma: camera
                .has_feature("Gamma")
                .then(|| camera.float("Gamma").ok())
                .flatten(),
        }
    }

    /// The gamma that decodes the frames, as the dataset states it (the inverse of the
    /// camera's Gamma, which raises the normalised value to its power on the way
    /// out): 1 for a camera without gamma or with it off; 2.2 for the sRGB curve (the
    /// exponent it approximates). None where a lookup table is on (any curve at all)
    /// or the value is out of the range a dataset accepts (above 0, at most 5).
    pub fn encoding_gamma(&self) -> Option<f64> {
        if self.lut_enable == Some(true) {
            return None;
        }
        if self.gamma_enable == Some(false) {
            return Some(1.0);
        }
        if self
            .gamma_selector
            .as_deref()
            .is_some_and(|s| s.eq_ignore_ascii_case("sRGB"))
        {
            return Some(2.2);
        }
        match self.gamma {
            None => Some(1.0),
            Some(g) if g.is_finite() && g >= 0.2 => Some(1.0 / g),
            Some(_) => None,
        }
    }
}

/// The decoder for a PixelFormat name, if there is one.
pub fn pixel_format_code(name: &str) -> Option<PixelFormat> {
    let code = match name {
        "Mono8" => 0x0108_0001,
        "Mono10" => 0x0110_0003,
        "Mono12" => 0x0110_0005,
        "Mono14" => 0x0110_0025,
        "Mono16" => 0x0110_0007,
        "Mono10p" => 0x010A_0046,
        "Mono12p" => 0x010C_0047,
        "Mono10Packed" => 0x010C_0004,
        "Mono12Packed" => 0x010C_0006,
        "BayerGR8" => 0x0108_0008,
        "BayerRG8" => 0x0108_0009,
        "BayerGB8" => 0x0108_000A,
        "BayerBG8" => 0x0108_000B,
        "BayerGR10" => 0x0110_000C,
        "BayerRG10" => 0x0110_000D,
        "BayerGB10" => 0x0110_000E,
        "BayerBG10" => 0x0110_000F,
        "BayerGR12" => 0x0110_0010,
        "BayerRG12" => 0x0110_0011,
        "BayerGB12" => 0x0110_0012,
        "BayerBG12" => 0x0110_0013,
        "BayerGR16" => 0x0110_002E,
        "BayerRG16" => 0x0110_002F,
        "BayerGB16" => 0x0110_0030,
        "BayerBG16" => 0x0110_0031,
        _ => return None,
    };
    PixelFormat::from_pfnc(code).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gamma_that_decodes_a_cameras_frames_follows_its_features() {
        let none = GammaFeatures::default();
        assert_eq!(
            none.encoding_gamma(),
            Some(1.0),
            "no gamma feature: raw counts"
        );
        let basler_display = GammaFeatures {
            gamma_enable: Some(true),
            gamma_selector: Some("User".into()),
            gamma: Some(0.45),
            ..GammaFeatures::default()
        };
        let decode = basler_display.encoding_gamma().unwrap();
        assert!((decode - 1.0 / 0.45).abs() < 1e-12, "{decode}");
        let off = GammaFeatures {
            gamma_enable: Some(false),
            ..basler_display.clone()
        };
        assert_eq!(off.encoding_gamma(), Some(1.0));
        let srgb = GammaFeatures {
            gamma_selector: Some("sRGB".into()),
            ..basler_display.clone()
        };
        assert_eq!(srgb.encoding_gamma(), Some(2.2));
        let lut = GammaFeatures {
            lut_enable: Some(true),
            ..GammaFeatures::default()
        };
        assert_eq!(
            lut.encoding_gamma(),
            None,
            "a lookup table can be any curve"
        );
        let ids_unity = GammaFeatures {
            gamma: Some(1.0),
            ..GammaFeatures::default()
        };
        assert_eq!(ids_unity.encoding_gamma(), Some(1.0));
        let beyond = GammaFeatures {
            gamma: Some(0.1),
            ..GammaFeatures::default()
        };
        assert_eq!(beyond.encoding_gamma(), None, "10 is beyond a dataset's 5");
    }

    #[test]
    fn a_file_and_flags_combine_flags_winning() {
        let file: CameraSettings = toml::from_str(
            "pixel_format = \"Mono12Packed\"\nexposure_us = 20000.0\ntrigger = \"Line0\"\nroi = [0, 0, 640, 480]\n",
        )
        .unwrap();
        let flags = CameraSettings {
            exposure_us: Some(5000.0),
            ..Default::default()
        };
        let s = file.overridden_by(flags);
        assert_eq!(s.exposure_us, Some(5000.0));
        assert_eq!(s.pixel_format.as_deref(), Some("Mono12Packed"));
        assert_eq!(s.roi, Some([0, 0, 640, 480]));
        assert_eq!(s.trigger.as_deref(), Some("Line0"));
    }

    #[test]
    fn an_unknown_key_is_refused_by_name() {
        let e = toml::from_str::<CameraSettings>("exposure = 3\n").unwrap_err();
        assert!(e.to_string().contains("exposure"), "{e}");
    }

    #[test]
    fn names_and_codes_agree() {
        for (name, bits) in [
            ("Mono8", 8),
            ("Mono12Packed", 12),
            ("Mono10p", 10),
            ("Mono16", 16),
        ] {
            assert_eq!(pixel_format_code(name).unwrap().bit_depth(), bits, "{name}");
        }
        assert_eq!(pixel_format_code("BayerRG8").unwrap().bayer(), Some("RGGB"));
        assert!(pixel_format_code("RGB8").is_none());
    }
}
