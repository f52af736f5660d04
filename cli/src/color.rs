//! Colours on the command line: a name, `#rrggbb` or `r,g,b`.

use fpm_protocol::Rgb;

/// Parse a colour argument.
pub fn parse(s: &str) -> Result<Rgb, String> {
    let named = match s.to_ascii_lowercase().as_str() {
        "white" => Some(Rgb::WHITE),
        "red" => Some(Rgb::new(255, 0, 0)),
        "green" => Some(Rgb::new(0, 255, 0)),
        "blue" => Some(Rgb::new(0, 0, 255)),
        "off" | "black" => Some(Rgb::OFF),
        _ => None,
    };
    if let Some(c) = named {
        return Ok(c);
    }
    if let Some(hex) = s.strip_prefix('#') {
        if hex.len() == 6 {
            if let Ok(v) = u32::from_str_radix(hex, 16) {
                return Ok(Rgb::new((v >> 16) as u8, (v >> 8) as u8, v as u8));
            }
        }
        return Err(format!("'{s}' is not a #rrggbb colour"));
    }
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() == 3 {
        let ch: Result<Vec<u8>, _> = parts.iter().map(|p| p.trim().parse::<u8>()).collect();
        if let Ok(ch) = ch {
            return Ok(Rgb::new(ch[0], ch[1], ch[2]));
        }
    }
    Err(format!(
        "'{s}' is not a colour: use white, red, green, blue, #rrggbb or r,g,b (0-255)"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours_parse_in_every_form() {
        assert_eq!(parse("White"), Ok(Rgb::WHITE));
        assert_eq!(parse("#0a0B0c"), Ok(Rgb::new(10, 11, 12)));
        assert_eq!(parse("1, 2,3"), Ok(Rgb::new(1, 2, 3)));
        assert!(parse("256,0,0").is_err());
        assert!(parse("#12345").is_err());
        assert!(parse("purple").is_err());
    }
}
