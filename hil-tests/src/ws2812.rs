//! Decode WS2812 bit streams from a pin trace into the colours the strip latched.
//!
//! A bit is one high pulse in a 1.25 µs slot: short (T0H, ~0.4 µs) for 0, long (T1H,
//! ~0.8 µs) for 1; the split is at 0.625 µs. A low gap longer than the reset time ends a
//! frame, which then latches. Pixels arrive as G, R, B bytes, most significant bit first.

use stereotac_protocol::Rgb;

use crate::trace::Edge;

/// High pulses longer than this are 1 bits, ns.
const ONE_THRESHOLD_NS: u64 = 625;
/// A low gap longer than this ends a frame (WS2812 reset is ≥ 50 µs), ns.
const FRAME_GAP_NS: u64 = 50_000;

/// One frame sent to a strip.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ws2812Frame {
    /// First rising edge, ns.
    pub start_ns: u64,
    /// Last falling edge, ns (the latch follows after the reset time).
    pub end_ns: u64,
    /// Pixels in strip order.
    pub pixels: Vec<Rgb>,
    /// Bits beyond the last whole pixel (0 for a well-formed frame).
    pub stray_bits: usize,
}

impl Ws2812Frame {
    /// Whether every pixel is dark.
    pub fn is_dark(&self) -> bool {
        self.pixels.iter().all(|p| (p.r, p.g, p.b) == (0, 0, 0))
    }
}

/// Decode the edges of one pin (any order of pins filtered out beforehand).
pub fn decode(edges: &[Edge]) -> Vec<Ws2812Frame> {
    let mut frames = Vec::new();
    let mut bits: Vec<bool> = Vec::new();
    let mut start = 0;
    let mut rise: Option<u64> = None;
    let mut last_fall = 0;
    let mut finish = |bits: &mut Vec<bool>, start: u64, end: u64| {
        if bits.is_empty() {
            return;
        }
        let bytes: Vec<u8> = bits
            .chunks_exact(8)
            .map(|b| b.iter().fold(0u8, |acc, &bit| (acc << 1) | u8::from(bit)))
            .collect();
        let pixels = bytes
            .chunks_exact(3)
            .map(|grb| Rgb::new(grb[1], grb[0], grb[2]))
            .collect();
        frames.push(Ws2812Frame {
            start_ns: start,
            end_ns: end,
            pixels,
            stray_bits: bits.len() % 24,
        });
        bits.clear();
    };
    for e in edges {
        if e.high {
            if !bits.is_empty() && e.t_ns - last_fall > FRAME_GAP_NS {
                finish(&mut bits, start, last_fall);
            }
            if bits.is_empty() {
                start = e.t_ns;
            }
            rise = Some(e.t_ns);
        } else if let Some(r) = rise.take() {
            bits.push(e.t_ns - r > ONE_THRESHOLD_NS);
            last_fall = e.t_ns;
        }
    }
    finish(&mut bits, start, last_fall);
    frames
}

#[cfg(test)]
mod tests {
    use super::*;

    fn encode(pixels: &[(u8, u8, u8)], t0: u64) -> Vec<Edge> {
        let mut edges = Vec::new();
        let mut t = t0;
        for &(r, g, b) in pixels {
            for byte in [g, r, b] {
                for i in (0..8).rev() {
                    let high = if byte >> i & 1 == 1 { 875 } else { 250 };
                    edges.push(Edge {
                        t_ns: t,
                        pin: 2,
                        high: true,
                    });
                    edges.push(Edge {
                        t_ns: t + high,
                        pin: 2,
                        high: false,
                    });
                    t += 1250;
                }
            }
        }
        edges
    }

    #[test]
    fn frames_decode_to_the_colours_sent_and_split_at_reset_gaps() {
        let mut edges = encode(&[(255, 0, 0), (0, 0, 200)], 1_000);
        edges.extend(encode(&[(1, 2, 3)], 400_000));
        let frames = decode(&edges);
        assert_eq!(frames.len(), 2);
        assert_eq!(
            frames[0].pixels,
            vec![Rgb::new(255, 0, 0), Rgb::new(0, 0, 200)]
        );
        assert_eq!(frames[0].start_ns, 1_000);
        assert_eq!(frames[0].end_ns, 1_000 + 47 * 1250 + 250);
        assert_eq!(frames[1].pixels, vec![Rgb::new(1, 2, 3)]);
        assert_eq!(frames[1].stray_bits, 0);
        assert!(!frames[1].is_dark());
        let mut short = encode(&[(0, 0, 0)], 0);
        short.truncate(10);
        let f = decode(&short);
        assert_eq!((f[0].pixels.len(), f[0].stray_bits), (0, 5));
    }
}
