//! OME-XML for the reconstruction's images (OME schema 2016-06): the pixel size in µm,
//! the channel's name and the microscope, so that Fiji/Bio-Formats, napari and
//! tifffile read the image with its physical units. Pure text; the TIFF writer
//! puts it into the first IFD's ImageDescription.

/// What an OME-TIFF image says about itself.
#[derive(Debug, Clone, Copy)]
pub struct OmeImage<'a> {
    /// Image and channel name (`amplitude`, `phase`).
    pub name: &'a str,
    /// What the values are (units, conventions).
    pub description: &'a str,
    /// Width and height, pixels.
    pub size: (usize, usize),
    /// Pixel side in the sample plane, µm.
    pub pixel_um: f64,
    /// Illumination wavelength, µm.
    pub wavelength_um: f64,
    /// Objective NA.
    pub na: f64,
    /// Objective magnification.
    pub magnification: f64,
}

/// `text` safe inside an XML attribute or element.
fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The OME-XML of one single-plane float32 image stored in IFD 0. ASCII only: the
/// units are the schema's defaults (µm for sizes, nm for wavelengths).
pub fn ome_xml(image: &OmeImage<'_>) -> String {
    ome_xml_channels(image, &[(image.name, image.wavelength_um)])
}

/// The OME-XML of one image of several float32 planes, one per channel (name and
/// wavelength, µm), stored in IFDs 0, 1, …: a colour reconstruction's.
pub fn ome_xml_channels(image: &OmeImage<'_>, channels: &[(&str, f64)]) -> String {
    let name = escape(image.name);
    let channel_xml: String = channels
        .iter()
        .enumerate()
        .map(|(k, (c, wavelength_um))| {
            format!(
                r#"<Channel ID="Channel:0:{k}" Name="{}" SamplesPerPixel="1" IlluminationType="Transmitted" ExcitationWavelength="{}"/>"#,
                escape(c),
                wavelength_um * 1e3
            )
        })
        .collect();
    let (w, h) = image.size;
    format!(
        concat!(
            r#"<?xml version="1.0" encoding="UTF-8"?>"#,
            r#"<OME xmlns="http://www.openmicroscopy.org/Schemas/OME/2016-06" "#,
            r#"xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" "#,
            r#"xsi:schemaLocation="http://www.openmicroscopy.org/Schemas/OME/2016-06 "#,
            r#"http://www.openmicroscopy.org/Schemas/OME/2016-06/ome.xsd" "#,
            r#"Creator="fpm {version}">"#,
            r#"<Instrument ID="Instrument:0">"#,
            r#"<Objective ID="Objective:0" LensNA="{na}" NominalMagnification="{mag}"/>"#,
            r#"</Instrument>"#,
            r#"<Image ID="Image:0" Name="{name}">"#,
            r#"<Description>{description}</Description>"#,
            r#"<InstrumentRef ID="Instrument:0"/>"#,
            r#"<ObjectiveSettings ID="Objective:0"/>"#,
            r#"<Pixels ID="Pixels:0" DimensionOrder="XYCZT" Type="float" "#,
            r#"SizeX="{w}" SizeY="{h}" SizeC="{c}" SizeZ="1" SizeT="1" "#,
            r#"PhysicalSizeX="{pixel}" PhysicalSizeY="{pixel}">"#,
            r#"{channels}"#,
            r#"<TiffData IFD="0" PlaneCount="{c}"/>"#,
            r#"</Pixels></Image></OME>"#
        ),
        version = env!("CARGO_PKG_VERSION"),
        na = image.na,
        mag = image.magnification,
        name = name,
        description = escape(image.description),
        w = w,
        h = h,
        pixel = image.pixel_um,
        c = channels.len(),
        channels = channel_xml,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xml_carries_size_units_and_escaped_names() {
        let xml = ome_xml(&OmeImage {
            name: "a<b",
            description: "radians & more",
            size: (640, 480),
            pixel_um: 0.40625,
            wavelength_um: 0.626,
            na: 0.1,
            magnification: 4.0,
        });
        assert!(xml.is_ascii());
        assert!(xml.contains(r#"SizeX="640" SizeY="480""#));
        assert!(xml.contains(r#"PhysicalSizeX="0.40625" PhysicalSizeY="0.40625""#));
        assert!(xml.contains(r#"Name="a&lt;b""#));
        assert!(xml.contains("radians &amp; more"));
        assert!(xml.contains(r#"ExcitationWavelength="626""#));
        assert!(xml.ends_with("</OME>"));
    }
}
