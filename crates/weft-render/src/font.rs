//! A built-in 5×7 bitmap font (printable ASCII), with two extra rows for
//! descenders, so charts need no font file.
//!
//! Each glyph is written as nine rows of five cells (`#` ink, `.` blank),
//! rows separated by spaces; rows 0–6 hold capitals and digits, lowercase
//! letters sit on rows 2–6, and `g j p q y , ;` reach into rows 7–8. The
//! table is parsed at compile time, so a malformed glyph does not build.

use crate::image::Image;

/// Glyph width in font pixels.
pub const GLYPH_WIDTH: u32 = 5;
/// Glyph height in font pixels, descenders included.
pub const GLYPH_HEIGHT: u32 = 9;
/// Horizontal advance per character (glyph plus one pixel of spacing).
pub const ADVANCE: u32 = GLYPH_WIDTH + 1;
/// Height of the capitals (rows 0–6).
pub const CAP_HEIGHT: u32 = 7;

/// Parses one glyph: up to nine rows of exactly five cells.
const fn glyph(s: &str) -> [u8; 9] {
    let b = s.as_bytes();
    let mut rows = [0u8; 9];
    let (mut i, mut row, mut col) = (0, 0, 0);
    while i < b.len() {
        match b[i] {
            b' ' => {
                assert!(col == 5, "a glyph row must have 5 cells");
                row += 1;
                col = 0;
            }
            c => {
                assert!(c == b'#' || c == b'.', "glyph cells are '#' or '.'");
                assert!(row < 9 && col < 5, "a glyph has at most 9 rows of 5 cells");
                if c == b'#' {
                    rows[row] |= 1 << (4 - col);
                }
                col += 1;
            }
        }
        i += 1;
    }
    assert!(col == 5, "a glyph row must have 5 cells");
    rows
}

/// Glyphs for the characters 32 (space) to 126 (`~`), in order.
const FONT: [(char, [u8; 9]); 95] = [
    (' ', glyph(".....")),
    ('!', glyph("..#.. ..#.. ..#.. ..#.. ..#.. ..... ..#..")),
    ('"', glyph(".#.#. .#.#. .....")),
    ('#', glyph(".#.#. .#.#. ##### .#.#. ##### .#.#. .#.#.")),
    ('$', glyph("..#.. .#### #.#.. .###. ..#.# ####. ..#..")),
    ('%', glyph("##... ##..# ...#. ..#.. .#... #..## ...##")),
    ('&', glyph(".##.. #..#. #.#.. .#... #.#.# #..#. .##.#")),
    ('\'', glyph("..#.. ..#.. .....")),
    ('(', glyph("...#. ..#.. .#... .#... .#... ..#.. ...#.")),
    (')', glyph(".#... ..#.. ...#. ...#. ...#. ..#.. .#...")),
    ('*', glyph("..... ..#.. #.#.# .###. #.#.# ..#.. .....")),
    ('+', glyph("..... ..#.. ..#.. ##### ..#.. ..#.. .....")),
    (
        ',',
        glyph("..... ..... ..... ..... ..... .##.. .##.. ..#.. .#..."),
    ),
    ('-', glyph("..... ..... ..... ##### ..... ..... .....")),
    ('.', glyph("..... ..... ..... ..... ..... .##.. .##..")),
    ('/', glyph("..... ....# ...#. ..#.. .#... #.... .....")),
    ('0', glyph(".###. #...# #..## #.#.# ##..# #...# .###.")),
    ('1', glyph("..#.. .##.. ..#.. ..#.. ..#.. ..#.. .###.")),
    ('2', glyph(".###. #...# ....# ...#. ..#.. .#... #####")),
    ('3', glyph("##### ...#. ..#.. ...#. ....# #...# .###.")),
    ('4', glyph("...#. ..##. .#.#. #..#. ##### ...#. ...#.")),
    ('5', glyph("##### #.... ####. ....# ....# #...# .###.")),
    ('6', glyph("..##. .#... #.... ####. #...# #...# .###.")),
    ('7', glyph("##### ....# ...#. ..#.. .#... .#... .#...")),
    ('8', glyph(".###. #...# #...# .###. #...# #...# .###.")),
    ('9', glyph(".###. #...# #...# .#### ....# ...#. .##..")),
    (':', glyph("..... .##.. .##.. ..... .##.. .##.. .....")),
    (
        ';',
        glyph("..... .##.. .##.. ..... .##.. .##.. ..#.. .#..."),
    ),
    ('<', glyph("...#. ..#.. .#... #.... .#... ..#.. ...#.")),
    ('=', glyph("..... ..... ##### ..... ##### ..... .....")),
    ('>', glyph(".#... ..#.. ...#. ....# ...#. ..#.. .#...")),
    ('?', glyph(".###. #...# ....# ...#. ..#.. ..... ..#..")),
    ('@', glyph(".###. #...# ....# .##.# #.#.# #.#.# .###.")),
    ('A', glyph(".###. #...# #...# ##### #...# #...# #...#")),
    ('B', glyph("####. #...# #...# ####. #...# #...# ####.")),
    ('C', glyph(".###. #...# #.... #.... #.... #...# .###.")),
    ('D', glyph("###.. #..#. #...# #...# #...# #..#. ###..")),
    ('E', glyph("##### #.... #.... ####. #.... #.... #####")),
    ('F', glyph("##### #.... #.... ####. #.... #.... #....")),
    ('G', glyph(".###. #...# #.... #.### #...# #...# .####")),
    ('H', glyph("#...# #...# #...# ##### #...# #...# #...#")),
    ('I', glyph(".###. ..#.. ..#.. ..#.. ..#.. ..#.. .###.")),
    ('J', glyph("..### ...#. ...#. ...#. ...#. #..#. .##..")),
    ('K', glyph("#...# #..#. #.#.. ##... #.#.. #..#. #...#")),
    ('L', glyph("#.... #.... #.... #.... #.... #.... #####")),
    ('M', glyph("#...# ##.## #.#.# #.#.# #...# #...# #...#")),
    ('N', glyph("#...# #...# ##..# #.#.# #..## #...# #...#")),
    ('O', glyph(".###. #...# #...# #...# #...# #...# .###.")),
    ('P', glyph("####. #...# #...# ####. #.... #.... #....")),
    ('Q', glyph(".###. #...# #...# #...# #.#.# #..#. .##.#")),
    ('R', glyph("####. #...# #...# ####. #.#.. #..#. #...#")),
    ('S', glyph(".#### #.... #.... .###. ....# ....# ####.")),
    ('T', glyph("##### ..#.. ..#.. ..#.. ..#.. ..#.. ..#..")),
    ('U', glyph("#...# #...# #...# #...# #...# #...# .###.")),
    ('V', glyph("#...# #...# #...# #...# #...# .#.#. ..#..")),
    ('W', glyph("#...# #...# #...# #.#.# #.#.# #.#.# .#.#.")),
    ('X', glyph("#...# #...# .#.#. ..#.. .#.#. #...# #...#")),
    ('Y', glyph("#...# #...# .#.#. ..#.. ..#.. ..#.. ..#..")),
    ('Z', glyph("##### ....# ...#. ..#.. .#... #.... #####")),
    ('[', glyph(".###. .#... .#... .#... .#... .#... .###.")),
    ('\\', glyph("..... #.... .#... ..#.. ...#. ....# .....")),
    (']', glyph(".###. ...#. ...#. ...#. ...#. ...#. .###.")),
    ('^', glyph("..#.. .#.#. #...#")),
    (
        '_',
        glyph("..... ..... ..... ..... ..... ..... ..... #####"),
    ),
    ('`', glyph(".#... ..#.. .....")),
    ('a', glyph("..... ..... .###. ....# .#### #...# .####")),
    ('b', glyph("#.... #.... #.##. ##..# #...# #...# ####.")),
    ('c', glyph("..... ..... .###. #.... #.... #...# .###.")),
    ('d', glyph("....# ....# .##.# #..## #...# #...# .####")),
    ('e', glyph("..... ..... .###. #...# ##### #.... .###.")),
    ('f', glyph("..##. .#..# .#... ###.. .#... .#... .#...")),
    (
        'g',
        glyph("..... ..... .#### #...# #...# #...# .#### ....# .###."),
    ),
    ('h', glyph("#.... #.... #.##. ##..# #...# #...# #...#")),
    ('i', glyph("..#.. ..... .##.. ..#.. ..#.. ..#.. .###.")),
    (
        'j',
        glyph("...#. ..... ..##. ...#. ...#. ...#. ...#. #..#. .##.."),
    ),
    ('k', glyph("#.... #.... #..#. #.#.. ##... #.#.. #..#.")),
    ('l', glyph(".##.. ..#.. ..#.. ..#.. ..#.. ..#.. .###.")),
    ('m', glyph("..... ..... ##.#. #.#.# #.#.# #.#.# #...#")),
    ('n', glyph("..... ..... #.##. ##..# #...# #...# #...#")),
    ('o', glyph("..... ..... .###. #...# #...# #...# .###.")),
    (
        'p',
        glyph("..... ..... ####. #...# #...# #...# ####. #.... #...."),
    ),
    (
        'q',
        glyph("..... ..... .#### #...# #...# #...# .#### ....# ....#"),
    ),
    ('r', glyph("..... ..... #.##. ##..# #.... #.... #....")),
    ('s', glyph("..... ..... .###. #.... .###. ....# ####.")),
    ('t', glyph(".#... .#... ###.. .#... .#... .#..# ..##.")),
    ('u', glyph("..... ..... #...# #...# #...# #..## .##.#")),
    ('v', glyph("..... ..... #...# #...# #...# .#.#. ..#..")),
    ('w', glyph("..... ..... #...# #...# #.#.# #.#.# .#.#.")),
    ('x', glyph("..... ..... #...# .#.#. ..#.. .#.#. #...#")),
    (
        'y',
        glyph("..... ..... #...# #...# #...# #...# .#### ....# .###."),
    ),
    ('z', glyph("..... ..... ##### ...#. ..#.. .#... #####")),
    ('{', glyph("...#. ..#.. ..#.. .#... ..#.. ..#.. ...#.")),
    (
        '|',
        glyph("..#.. ..#.. ..#.. ..#.. ..#.. ..#.. ..#.. ..#.."),
    ),
    ('}', glyph(".#... ..#.. ..#.. ...#. ..#.. ..#.. .#...")),
    ('~', glyph("..... ..... .#... #.#.# ...#. ..... .....")),
];

/// Drawn for characters outside printable ASCII.
const UNKNOWN: [u8; 9] = glyph("##### #...# #...# #...# #...# #...# #####");

/// The rows of `c`'s glyph (bit 4 is the leftmost cell).
pub fn glyph_rows(c: char) -> [u8; 9] {
    let code = c as u32;
    if (32..127).contains(&code) {
        FONT[(code - 32) as usize].1
    } else {
        UNKNOWN
    }
}

/// Width in pixels of `text` drawn at `scale` (no trailing spacing).
pub fn text_width(text: &str, scale: u32) -> u32 {
    let n = text.chars().count() as u32;
    (n * ADVANCE).saturating_sub(1) * scale
}

/// Draws `text` with its top-left corner at `(x, y)`, each font pixel a
/// `scale × scale` square.
pub fn draw_text(img: &mut Image, x: i64, y: i64, text: &str, scale: u32, color: [u8; 3]) {
    let s = scale as i64;
    for (k, c) in text.chars().enumerate() {
        let gx = x + k as i64 * ADVANCE as i64 * s;
        for (row, bits) in glyph_rows(c).iter().enumerate() {
            for col in 0..GLYPH_WIDTH {
                if bits & (1 << (4 - col)) != 0 {
                    let px = gx + col as i64 * s;
                    let py = y + row as i64 * s;
                    img.fill_rect(px, py, px + s, py + s, color);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_is_in_ascii_order_and_glyphs_have_ink() {
        for (i, (c, rows)) in FONT.iter().enumerate() {
            assert_eq!(*c as u32, 32 + i as u32, "glyph {i} is {c:?}");
            if *c != ' ' {
                assert!(rows.iter().any(|&r| r != 0), "{c:?} is blank");
            }
        }
        // Distinct glyphs for distinct characters.
        for a in 0..FONT.len() {
            for b in a + 1..FONT.len() {
                assert_ne!(FONT[a].1, FONT[b].1, "{:?} == {:?}", FONT[a].0, FONT[b].0);
            }
        }
    }

    #[test]
    fn text_is_drawn_where_asked() {
        let mut img = Image::new(40, 20, [255; 3]);
        draw_text(&mut img, 2, 3, "1e-5", 1, [0; 3]);
        assert_eq!(text_width("1e-5", 1), 23);
        assert!(img.count_not([255; 3]) > 20);
        // Nothing left of x = 2 or above y = 3.
        for y in 0..20 {
            assert_eq!(img.pixel(0, y), [255; 3]);
            assert_eq!(img.pixel(1, y), [255; 3]);
        }
        for x in 0..40 {
            assert_eq!(img.pixel(x, 2), [255; 3]);
        }
    }
}
