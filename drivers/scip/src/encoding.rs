//! SCIP character-level facts: the 6-bit line sum and the 6-bit-per-character value encoding.

/// Longest data block of one payload line; longer payloads continue on the next line.
pub const MAX_BLOCK: usize = 64;

/// Line sum as SCIP defines it: the low six bits of the byte sum, offset into printable ASCII.
pub fn checksum(bytes: &[u8]) -> u8 {
    let sum = bytes.iter().fold(0u8, |acc, &b| acc.wrapping_add(b));
    (sum & 0x3F) + 0x30
}

/// Decodes a big-endian run of 6-bit characters; `None` if a character is outside `0x30..=0x6F`.
pub fn decode_value(chars: &[u8]) -> Option<u32> {
    chars.iter().try_fold(0u32, |acc, &c| {
        let six = c.wrapping_sub(0x30);
        (six < 64).then_some((acc << 6) | u32::from(six))
    })
}

/// Appends `value` as `width` 6-bit characters; bits above `6 * width` are dropped, so callers
/// clamp first.
pub fn encode_value(value: u32, width: usize, out: &mut Vec<u8>) {
    for i in (0..width).rev() {
        out.push(((value >> (6 * i)) & 0x3F) as u8 + 0x30);
    }
}

/// Appends `line` followed by its sum and LF.
pub fn push_summed_line(line: &[u8], out: &mut Vec<u8>) {
    out.extend_from_slice(line);
    out.push(checksum(line));
    out.push(b'\n');
}

/// Appends an encoded data payload as 64-character blocks, each with its own sum and LF.
pub fn push_data_blocks(data: &[u8], out: &mut Vec<u8>) {
    for block in data.chunks(MAX_BLOCK) {
        push_summed_line(block, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_examples_encode_and_decode() {
        for (value, width, text) in [
            (1234, 2, &b"CB"[..]),
            (5432, 3, b"1Dh"),
            (16_000_000, 4, b"m2@0"),
        ] {
            let mut out = Vec::new();
            encode_value(value, width, &mut out);
            assert_eq!(out, text);
            assert_eq!(decode_value(text), Some(value));
        }
    }

    #[test]
    fn status_sums_match_the_protocol_table() {
        for line in ["00P", "99b", "02R", "0Ee", "10Q", "0Mm"] {
            let b = line.as_bytes();
            assert_eq!(checksum(&b[..2]), b[2], "{line}");
        }
    }

    #[test]
    fn characters_outside_the_alphabet_are_rejected() {
        assert_eq!(decode_value(b"0p"), None);
        assert_eq!(decode_value(b"/0"), None);
    }
}
