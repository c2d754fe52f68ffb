//! H.264 video files for `b2tf track --video` (feature `video`): an MP4 / QuickTime
//! container (`mp4` crate, pure Rust) or a raw Annex-B stream, decoded by OpenH264 (the
//! `openh264` crate, Cisco's C source compiled by `cc`). Streaming: one access unit is read
//! and one picture decoded at a time; only the MP4 sample tables are held in memory.
//!
//! Pictures are converted to RGB with BT.601 limited-range coefficients (what OpenH264's
//! encoder and most cameras write; a full-range flag in the stream is not looked at).
//! A decoding error ends the frames with that error after the pictures before it: a cut
//! Annex-B stream gives its complete frames, then either stops (the cut fell between
//! frames) or names the frame it could not decode.

use anyhow::{anyhow, bail, Context, Result};
use openh264::decoder::Decoder;
use openh264::formats::YUVSource;
use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

pub use super::Container;

/// Access units (the NAL units of one picture, each after a 4-byte start code) in
/// decoding order.
trait AccessUnits {
    fn next_unit(&mut self) -> Result<Option<Vec<u8>>>;
}

/// The decoded pictures of an H.264 file as RGB, in the decoder's output order.
pub struct H264Frames {
    units: Box<dyn AccessUnits>,
    decoder: Decoder,
    flushed: VecDeque<image::RgbImage>,
    done: bool,
    decoded: usize,
    label: String,
}

impl H264Frames {
    pub fn open(path: &Path, container: Container) -> Result<Self> {
        let label = path.display().to_string();
        let file = File::open(path).with_context(|| format!("cannot open the video file {label}"))?;
        let units: Box<dyn AccessUnits> = match container {
            Container::Mp4 => Box::new(Mp4Units::open(file, &label)?),
            Container::AnnexB => Box::new(AnnexB::open(file, &label)?),
        };
        let decoder = Decoder::new().map_err(|e| anyhow!("cannot start the H.264 decoder: {e}"))?;
        Ok(Self { units, decoder, flushed: VecDeque::new(), done: false, decoded: 0, label })
    }

    fn step(&mut self) -> Result<Option<image::RgbImage>> {
        loop {
            if let Some(image) = self.flushed.pop_front() {
                return Ok(Some(image));
            }
            if self.done {
                return Ok(None);
            }
            let Some(unit) = self.units.next_unit()? else {
                // The end: pictures the decoder still holds (reordering) come out now.
                self.done = true;
                let rest = self.decoder.flush_remaining().map_err(|e| anyhow!("{}: flushing the decoder: {e}", self.label))?;
                for yuv in rest {
                    self.flushed.push_back(yuv_to_rgb(&yuv)?);
                }
                continue;
            };
            let picture = self.decoder.decode(&unit).map_err(|e| anyhow!("{}: cannot decode frame {} (the stream is cut or corrupt): {e}", self.label, self.decoded))?;
            if let Some(yuv) = picture {
                return yuv_to_rgb(&yuv).map(Some);
            }
        }
    }
}

impl Iterator for H264Frames {
    type Item = Result<image::RgbImage>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done && self.flushed.is_empty() {
            return None;
        }
        match self.step() {
            Ok(Some(image)) => {
                self.decoded += 1;
                Some(Ok(image))
            }
            Ok(None) => None,
            Err(e) => {
                // After an error the stream is not trusted any further.
                self.done = true;
                self.flushed.clear();
                Some(Err(e))
            }
        }
    }
}

/// I420 (any strides; odd sizes take the chroma sample of their 2×2 block) to RGB with the
/// BT.601 limited-range ("TV") matrix, in 8.8 fixed point.
pub fn yuv_to_rgb(yuv: &impl YUVSource) -> Result<image::RgbImage> {
    let (w, h) = yuv.dimensions();
    let (sy, su, sv) = yuv.strides();
    let (y, u, v) = (yuv.y(), yuv.u(), yuv.v());
    let (cw, ch) = (w.div_ceil(2), h.div_ceil(2));
    let fits = |plane: &[u8], stride: usize, width: usize, rows: usize| rows == 0 || (stride >= width && plane.len() >= (rows - 1) * stride + width);
    // The decoder may hand the chroma planes one row short for an odd height: the last
    // luma row then takes the row above's chroma.
    let chroma_rows = |plane: &[u8], stride: usize| (plane.len() + stride).saturating_sub(cw).checked_div(stride).map_or(0, |rows| ch.min(rows));
    let (ru, rv) = (chroma_rows(u, su), chroma_rows(v, sv));
    if w == 0 || h == 0 || !fits(y, sy, w, h) || ru == 0 || rv == 0 || !fits(u, su, cw, ru) || !fits(v, sv, cw, rv) {
        bail!("the decoder returned a {w}×{h} picture with planes of {}/{}/{} bytes (strides {sy}/{su}/{sv})", y.len(), u.len(), v.len());
    }
    let w32 = u32::try_from(w).context("picture width")?;
    let h32 = u32::try_from(h).context("picture height")?;
    let mut rgb = vec![0u8; w * h * 3];
    let clamp = |x: i32| (x >> 8).clamp(0, 255) as u8;
    for (row, out) in rgb.chunks_exact_mut(w * 3).enumerate() {
        let y_row = &y[row * sy..row * sy + w];
        let u_row = &u[(row / 2).min(ru - 1) * su..][..cw];
        let v_row = &v[(row / 2).min(rv - 1) * sv..][..cw];
        for (col, px) in out.chunks_exact_mut(3).enumerate() {
            let c = 298 * (i32::from(y_row[col]) - 16) + 128;
            let d = i32::from(u_row[col / 2]) - 128;
            let e = i32::from(v_row[col / 2]) - 128;
            px[0] = clamp(c + 409 * e);
            px[1] = clamp(c - 100 * d - 208 * e);
            px[2] = clamp(c + 516 * d);
        }
    }
    image::RgbImage::from_raw(w32, h32, rgb).context("RGB buffer")
}

/// Runs a call into the MP4 parser, turning a panic on a malformed file into an error.
fn guarded<T>(what: &str, f: impl FnOnce() -> mp4::Result<T>) -> Result<T> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r.map_err(|e| anyhow!("{what}: {e}")),
        Err(_) => bail!("{what}: malformed MP4 data"),
    }
}

/// Where the child boxes of a box the `mp4` crate walks begin, after its header: None for
/// a box it does not look into.
fn children_offset(kind: &[u8; 4], parent: &[u8; 4], payload: &mut (impl Read + Seek)) -> std::io::Result<Option<u64>> {
    Ok(match kind {
        // The items of an `ilst` hold `data` boxes.
        _ if parent == b"ilst" => Some(0),
        b"moov" | b"trak" | b"mdia" | b"minf" | b"stbl" | b"dinf" | b"udta" | b"mvex" | b"moof" | b"traf" | b"edts" | b"ilst" => Some(0),
        b"stsd" | b"dref" => Some(8),
        b"avc1" | b"hev1" => Some(78),
        b"mp4a" => Some(28),
        // A full box, or (QuickTime) a plain one that starts with its `hdlr`.
        b"meta" => {
            let mut head = [0u8; 8];
            payload.read_exact(&mut head)?;
            Some(if &head[4..] == b"hdlr" { 0 } else { 4 })
        }
        _ => None,
    })
}

/// The box tree from `start` to `end` is sound where the `mp4` crate walks it: every box at
/// least as long as its header and inside its parent. (The crate loops forever on a child
/// box shorter than 8 bytes: it seeks back to read the same header again.)
fn check_boxes(file: &mut (impl Read + Seek), start: u64, end: u64, parent: [u8; 4], depth: usize) -> Result<()> {
    let mut at = start;
    while at < end {
        if depth > 16 {
            bail!("boxes nested more than 16 deep");
        }
        if end - at < 8 {
            bail!("{} stray bytes at offset {at}", end - at);
        }
        file.seek(SeekFrom::Start(at))?;
        let mut head = [0u8; 8];
        file.read_exact(&mut head)?;
        let kind: [u8; 4] = head[4..].try_into()?;
        let (size, header) = match u32::from_be_bytes(head[..4].try_into()?) {
            1 => {
                let mut large = [0u8; 8];
                file.read_exact(&mut large)?;
                (u64::from_be_bytes(large), 16)
            }
            // To the end of the file: only the last box at the top.
            0 if depth == 0 => (end - at, 8),
            n => (u64::from(n), 8),
        };
        let name = String::from_utf8_lossy(&kind).into_owned();
        if size < header || size > end - at {
            bail!("box '{name}' at offset {at} claims {size} bytes, {} available", end - at);
        }
        if let Some(offset) = children_offset(&kind, &parent, file)? {
            check_boxes(file, (at + header + offset).min(at + size), at + size, kind, depth + 1).with_context(|| format!("in box '{name}' at offset {at}"))?;
        }
        at += size;
    }
    Ok(())
}

/// The samples of an MP4's first H.264 track, read one at a time.
struct Mp4Units {
    reader: mp4::Mp4Reader<BufReader<File>>,
    track: u32,
    next: u32,
    count: u32,
    length_size: usize,
    /// The SPS and PPS from the track's `avcC`, put before the first sample.
    parameter_sets: Option<Vec<u8>>,
    label: String,
}

impl Mp4Units {
    fn open(file: File, label: &str) -> Result<Self> {
        let size = file.metadata().with_context(|| format!("cannot read the video file {label}"))?.len();
        let not_mp4 = format!("{label} is not a readable MP4/QuickTime file");
        let mut file = BufReader::new(file);
        check_boxes(&mut file, 0, size, *b"file", 0).with_context(|| not_mp4.clone())?;
        file.seek(SeekFrom::Start(0)).with_context(|| format!("cannot read the video file {label}"))?;
        let reader = guarded(&not_mp4, || mp4::Mp4Reader::read_header(file, size))?;
        let mut tracks: Vec<&mp4::Mp4Track> = reader.tracks().values().collect();
        tracks.sort_by_key(|t| t.track_id());
        let Some(track) = tracks.iter().find(|t| matches!(t.media_type(), Ok(mp4::MediaType::H264))) else {
            let kinds: Vec<String> = tracks.iter().map(|t| t.media_type().map_or_else(|_| t.box_type().map_or("unknown".into(), |b| b.to_string()), |m| m.to_string())).collect();
            bail!("{label} has no H.264 video track (tracks: {}); only H.264 is decoded", if kinds.is_empty() { "none".into() } else { kinds.join(", ") });
        };
        let stbl = &track.trak.mdia.minf.stbl;
        // A sample larger than the file is a broken table: refused before allocating it.
        if stbl.stsz.sample_size as u64 > size || stbl.stsz.sample_sizes.iter().any(|&s| s as u64 > size) {
            bail!("{not_mp4}: a sample is larger than the file");
        }
        let avcc = &stbl.stsd.avc1.as_ref().context("avc1")?.avcc;
        let mut parameter_sets = Vec::new();
        for nal in avcc.sequence_parameter_sets.iter().chain(&avcc.picture_parameter_sets) {
            parameter_sets.extend_from_slice(&[0, 0, 0, 1]);
            parameter_sets.extend_from_slice(&nal.bytes);
        }
        let count = guarded(&not_mp4, || Ok(track.sample_count()))?;
        let (id, length_size) = (track.track_id(), usize::from(avcc.length_size_minus_one & 3) + 1);
        Ok(Self { reader, track: id, next: 1, count, length_size, parameter_sets: Some(parameter_sets), label: label.to_string() })
    }
}

impl AccessUnits for Mp4Units {
    fn next_unit(&mut self) -> Result<Option<Vec<u8>>> {
        if self.next > self.count {
            return Ok(None);
        }
        let id = self.next;
        self.next += 1;
        let what = format!("{}: reading sample {id} of {} (the file is cut or corrupt)", self.label, self.count);
        let Some(sample) = guarded(&what, || self.reader.read_sample(self.track, id))? else { return Ok(None) };
        let mut unit = self.parameter_sets.take().unwrap_or_default();
        // Length-prefixed NAL units (avcC) to start codes.
        let mut rest: &[u8] = &sample.bytes;
        while !rest.is_empty() {
            let len = (rest.len() >= self.length_size).then(|| rest[..self.length_size].iter().fold(0usize, |a, &b| a << 8 | usize::from(b)));
            let Some(nal) = len.and_then(|n| rest.get(self.length_size..self.length_size + n)) else { bail!("{what}: a NAL unit runs past the sample's end") };
            unit.extend_from_slice(&[0, 0, 0, 1]);
            unit.extend_from_slice(nal);
            rest = &rest[self.length_size + nal.len()..];
        }
        Ok(Some(unit))
    }
}

/// A raw Annex-B stream, read in chunks and split into NAL units at their start codes,
/// which are grouped into access units.
struct AnnexB<R> {
    reader: R,
    /// Unread bytes; from the start of the current NAL unit (after its start code) on.
    buf: Vec<u8>,
    /// Where the search for the next start code goes on in `buf`.
    scan: usize,
    eof: bool,
    /// The access unit being gathered, and whether it has a slice yet.
    unit: Vec<u8>,
    unit_has_slice: bool,
}

const CHUNK: usize = 1 << 16;

/// The first 00 00 01 in `data` at or after `from`: (where its zeros start, where the NAL
/// unit after it starts). A longer run of zeros before it belongs to it.
fn start_code(data: &[u8], from: usize) -> Option<(usize, usize)> {
    let at = data.get(from..)?.windows(3).position(|w| w == [0, 0, 1])? + from;
    let zeros = data[..at].iter().rev().take_while(|&&b| b == 0).count();
    Some((at - zeros, at + 3))
}

impl<R: Read> AnnexB<R> {
    fn open(reader: R, label: &str) -> Result<Self> {
        let mut s = Self { reader, buf: Vec::new(), scan: 0, eof: false, unit: Vec::new(), unit_has_slice: false };
        // The stream must start with a start code (after zeros at most).
        while s.buf.len() < 4 && !s.eof {
            s.fill().with_context(|| format!("cannot read the video file {label}"))?;
        }
        match start_code(&s.buf, 0) {
            Some((0, next)) => {
                s.buf.drain(..next);
            }
            _ => bail!("{label} is not an H.264 Annex-B stream (it does not start with a 00 00 01 start code)"),
        }
        Ok(s)
    }

    fn fill(&mut self) -> std::io::Result<()> {
        let old = self.buf.len();
        self.buf.resize(old + CHUNK, 0);
        let n = loop {
            match self.reader.read(&mut self.buf[old..]) {
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                r => break r,
            }
        };
        self.buf.truncate(old + *n.as_ref().unwrap_or(&0));
        self.eof |= matches!(n, Ok(0));
        n.map(|_| ())
    }

    /// The next NAL unit (without its start code), or None at the end.
    fn next_nal(&mut self) -> Result<Option<Vec<u8>>> {
        loop {
            if let Some((end, next)) = start_code(&self.buf, self.scan) {
                let nal = self.buf[..end].to_vec();
                self.buf.drain(..next);
                self.scan = 0;
                return Ok(Some(nal));
            }
            if self.eof {
                if self.buf.is_empty() {
                    return Ok(None);
                }
                return Ok(Some(std::mem::take(&mut self.buf)));
            }
            // Keep the last two bytes in the search: a start code may straddle chunks.
            self.scan = self.buf.len().saturating_sub(2);
            self.fill().context("reading the video file")?;
        }
    }
}

/// Whether a NAL unit starts a new access unit once the current one has a slice: an access
/// unit delimiter, SEI, SPS, PPS or reserved (6–9, 14–18), or the first slice of a picture
/// (first_mb_in_slice = 0, whose Exp-Golomb code is the single bit 1).
fn starts_access_unit(nal: &[u8]) -> bool {
    match nal.first().map(|b| b & 0x1f) {
        Some(1 | 5) => nal.get(1).is_some_and(|b| b & 0x80 != 0),
        Some(6..=9 | 14..=18) => true,
        _ => false,
    }
}

impl<R: Read> AccessUnits for AnnexB<R> {
    fn next_unit(&mut self) -> Result<Option<Vec<u8>>> {
        while let Some(nal) = self.next_nal()? {
            if nal.is_empty() {
                continue;
            }
            let done = self.unit_has_slice && starts_access_unit(&nal);
            let finished = done.then(|| std::mem::take(&mut self.unit));
            if done {
                self.unit_has_slice = false;
            }
            self.unit_has_slice |= matches!(nal[0] & 0x1f, 1..=5);
            self.unit.extend_from_slice(&[0, 0, 0, 1]);
            self.unit.extend_from_slice(&nal);
            if finished.is_some() {
                return Ok(finished);
            }
        }
        Ok((!self.unit.is_empty()).then(|| std::mem::take(&mut self.unit)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Planes {
        dims: (usize, usize),
        strides: (usize, usize, usize),
        y: Vec<u8>,
        u: Vec<u8>,
        v: Vec<u8>,
    }

    impl YUVSource for Planes {
        fn dimensions(&self) -> (usize, usize) {
            self.dims
        }
        fn strides(&self) -> (usize, usize, usize) {
            self.strides
        }
        fn y(&self) -> &[u8] {
            &self.y
        }
        fn u(&self) -> &[u8] {
            &self.u
        }
        fn v(&self) -> &[u8] {
            &self.v
        }
    }

    #[test]
    fn bt601_limited_range_at_odd_sizes_and_padded_strides() {
        // 5×3 with strides 8 / 4: black, white and red (BT.601 limited: Y 81, U 90, V 240).
        let (w, h, sy, sc) = (5, 3, 8, 4);
        let mut p = Planes { dims: (w, h), strides: (sy, sc, sc), y: vec![16; sy * h], u: vec![128; sc * 2], v: vec![128; sc * 2] };
        p.y[sy + 2] = 235; // (2, 1) white
        p.y[2 * sy + 4] = 81; // (4, 2): the odd corner, chroma block (2, 1)
        p.u[sc + 2] = 90;
        p.v[sc + 2] = 240;
        let rgb = yuv_to_rgb(&p).unwrap();
        assert_eq!(rgb.dimensions(), (5, 3));
        assert_eq!(rgb.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(rgb.get_pixel(2, 1).0, [255, 255, 255]);
        let red = rgb.get_pixel(4, 2).0;
        assert!(red[0] >= 250 && red[1] <= 3 && red[2] <= 3, "{red:?}");
        // Chroma one row short for the odd height: the last row borrows the row above's.
        p.u.truncate(sc);
        p.v.truncate(sc);
        assert_eq!(yuv_to_rgb(&p).unwrap().get_pixel(2, 1).0, [255, 255, 255]);
        // Planes too small for the size: an error, not a panic.
        p.y.truncate(sy);
        assert!(yuv_to_rgb(&p).unwrap_err().to_string().contains("5×3"));
    }

    #[test]
    fn annex_b_splits_into_access_units_across_chunks() {
        // SPS, PPS, an IDR picture in two slices (the second with first_mb_in_slice ≠ 0),
        // then a P slice; 4- and 3-byte start codes.
        let mut stream = Vec::new();
        let nals: [&[u8]; 5] = [&[0x67, 1, 2], &[0x68, 3], &[0x65, 0x88, 4], &[0x65, 0x40, 5], &[0x41, 0x9a, 6]];
        for (i, nal) in nals.iter().enumerate() {
            stream.extend_from_slice(if i % 2 == 0 { &[0, 0, 0, 1][..] } else { &[0, 0, 1][..] });
            stream.extend_from_slice(nal);
        }
        // A reader that hands out one byte at a time: every start code straddles reads.
        struct Trickle(Vec<u8>, usize);
        impl Read for Trickle {
            fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
                let n = usize::from(self.1 < self.0.len() && !out.is_empty());
                out[..n].copy_from_slice(&self.0[self.1..self.1 + n]);
                self.1 += n;
                Ok(n)
            }
        }
        let mut units = AnnexB::open(Trickle(stream, 0), "t").unwrap();
        let with_codes = |nals: &[&[u8]]| nals.iter().flat_map(|n| [&[0, 0, 0, 1][..], n].concat()).collect::<Vec<u8>>();
        assert_eq!(units.next_unit().unwrap().unwrap(), with_codes(&nals[..4]));
        assert_eq!(units.next_unit().unwrap().unwrap(), with_codes(&nals[4..]));
        assert!(units.next_unit().unwrap().is_none());
        let Err(e) = AnnexB::open(&b"hello"[..], "t.h264") else { panic!("text read as a stream") };
        assert!(e.to_string().contains("not an H.264 Annex-B stream"), "{e}");
    }
}
