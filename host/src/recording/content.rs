//! A recording's content as the pipeline takes it: [`frames`] reads a file through and
//! joins each camera's images with their labels (for `process`, `export` and
//! `calibrate`), [`stream`] hands the same out one item at a time from a reading thread
//! (the Python package). Both read with [`RecordingReader`], so a cut or damaged file is
//! read as far as it can be, and its note comes back with the content.

use std::collections::HashMap;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use foxglove::Decode;
use foxglove::messages::RawImage;
use image::RgbImage;

use super::messages::{FrameInfo, rgb_from_raw};
use super::reader::{Record, RecordingHeader, RecordingReader};
use super::{RecordingError, topics};
use crate::frames::Frame;
use crate::frames::capture::LabelledFrame;
use crate::matcher::Label;

/// A recorded camera frame with its label.
#[derive(Debug, Clone)]
pub struct RecordedFrame {
    /// Camera number.
    pub camera: usize,
    /// Timing and label, as recorded.
    pub info: FrameInfo,
    /// The label, read from `info` (checked).
    pub label: Label,
    /// Pixels.
    pub image: RgbImage,
}

impl RecordedFrame {
    /// The frame as the live pipeline takes it.
    pub fn into_labelled(self) -> LabelledFrame {
        LabelledFrame {
            frame: Frame {
                stamp: self.info.stamp(),
                image: self.image,
            },
            label: self.label,
        }
    }
}

/// Everything in a recording by kind, in order: frames (image joined with its label),
/// other messages, and the header (metadata, attachments) as it is met.
#[derive(Debug, Clone)]
pub enum Content {
    /// A labelled frame.
    Frame(RecordedFrame),
    /// Any other message.
    Other(Record),
}

/// Most frame labels kept waiting for their images. A recording from `record` or `run`
/// writes each image right after its label, so a handful wait at a time; this bounds the
/// memory a damaged or hostile file can take.
pub const MAX_PENDING_LABELS: usize = 4096;

/// Reads `path` through, joining frames: `each` gets every labelled frame and every
/// other message in file order (and may break off); the header is returned with how the
/// file ended.
/// A frame's image and label are joined by camera and timestamp (the label comes
/// first); an image whose label never came is reported, not guessed, and so is a label
/// whose image never came (unless `each` broke off: the image may have been still to
/// come).
pub fn frames<E: From<RecordingError>>(
    path: &Path,
    mut each: impl FnMut(Content, (u64, u64)) -> Result<ControlFlow<()>, E>,
) -> Result<(RecordingHeader, Option<String>), E> {
    let mut reader = RecordingReader::open(path)?;
    let mut header = RecordingHeader::default();
    let mut labels: HashMap<(usize, u64), (FrameInfo, Label)> = HashMap::new();
    let mut unlabelled = 0u64;
    // The caller broke off: labels still waiting may have had their images still to come
    // (a writer that puts other messages between a label and its image), so they are not
    // counted as lost.
    let mut stopped = false;
    let bad = |topic: &str, log_time_ns, message: String| RecordingError::Message {
        path: path.to_path_buf(),
        topic: topic.to_string(),
        log_time_ns,
        message,
    };
    while let Some(record) = reader.next_record() {
        let record = record?;
        let progress = reader.progress();
        match &record {
            Record::Message {
                topic,
                log_time_ns,
                data,
                ..
            } => match topics::camera_of(topic) {
                Some(camera) if *topic == topics::camera_frame(camera) => {
                    let info: FrameInfo = serde_json::from_slice(data)
                        .map_err(|e| bad(topic, *log_time_ns, e.to_string()))?;
                    let label = info.label().map_err(|e| bad(topic, *log_time_ns, e))?;
                    labels.insert((camera, *log_time_ns), (info, label));
                    if labels.len() > MAX_PENDING_LABELS {
                        return Err(bad(
                            topic,
                            *log_time_ns,
                            format!(
                                "more than {MAX_PENDING_LABELS} frame labels without their images: \
                                 not a recording `record` or `run` writes (each label is followed by its image)"
                            ),
                        )
                        .into());
                    }
                }
                Some(camera) if *topic == topics::camera_image(camera) => {
                    let raw = RawImage::decode(data.as_slice())
                        .map_err(|e| bad(topic, *log_time_ns, e.to_string()))?;
                    let image = rgb_from_raw(&raw).map_err(|e| bad(topic, *log_time_ns, e))?;
                    let Some((info, label)) = labels.remove(&(camera, *log_time_ns)) else {
                        // Its label may have been in a damaged chunk that was skipped:
                        // the image is skipped too, and counted.
                        if reader.skipped_chunks() > 0 {
                            unlabelled += 1;
                            continue;
                        }
                        return Err(bad(
                            topic,
                            *log_time_ns,
                            format!(
                                "no label on {} for this image (same log time)",
                                topics::camera_frame(camera)
                            ),
                        )
                        .into());
                    };
                    if each(
                        Content::Frame(RecordedFrame {
                            camera,
                            info,
                            label,
                            image,
                        }),
                        progress,
                    )?
                    .is_break()
                    {
                        stopped = true;
                        break;
                    }
                }
                _ => {
                    if each(Content::Other(record), progress)?.is_break() {
                        stopped = true;
                        break;
                    }
                }
            },
            Record::Metadata { name, entries } => {
                header.metadata.insert(name.clone(), entries.clone());
                if each(Content::Other(record), progress)?.is_break() {
                    stopped = true;
                    break;
                }
            }
            Record::Attachment { name, data, .. } => {
                header.attachments.insert(name.clone(), data.clone());
                if each(Content::Other(record), progress)?.is_break() {
                    stopped = true;
                    break;
                }
            }
        }
    }
    let mut note = reader.truncated().map(str::to_string);
    add_count(
        &mut note,
        unlabelled as usize,
        "image whose label was in a damaged chunk was skipped",
        "images whose labels were in a damaged chunk were skipped",
    );
    // Labels whose images never came: in a damaged chunk, or after where the reading
    // ended (a cut file). Their frames are lost as well, and counted.
    if !stopped {
        add_count(
            &mut note,
            labels.len(),
            "frame label whose image never came (in a damaged chunk, or after where the reading ended) was skipped",
            "frame labels whose images never came (in a damaged chunk, or after where the reading ended) were skipped",
        );
    }
    Ok((header, note))
}

/// Adds "`n` `many`" ("1 `one`" when `n` is 1) to the reading's note, after what it says
/// already; nothing when `n` is 0.
fn add_count(note: &mut Option<String>, n: usize, one: &str, many: &str) {
    let said = match n {
        0 => return,
        1 => format!("1 {one}"),
        n => format!("{n} {many}"),
    };
    *note = Some(note.take().map_or(said.clone(), |s| format!("{s}; {said}")));
}

/// What [`stream`] hands on.
#[derive(Debug)]
enum Fed {
    Content(Box<Content>),
    End(Option<String>),
    Failed(RecordingError),
}

/// [`frames`] as an iterator (pull instead of push), for callers that take one item at a
/// time (the Python package): a thread reads ahead by at most `ahead` items; dropping
/// the iterator stops it.
pub struct ContentStream {
    rx: std::sync::mpsc::Receiver<Fed>,
    truncated: Option<String>,
    done: bool,
}

impl std::fmt::Debug for ContentStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContentStream")
            .field("done", &self.done)
            .finish_non_exhaustive()
    }
}

/// Streams `path`'s contents in file order (see [`frames`]); opening errors come as the
/// first item.
pub fn stream(path: &Path, ahead: usize) -> ContentStream {
    let (tx, rx) = std::sync::mpsc::sync_channel(ahead.max(1));
    let path = path.to_path_buf();
    std::thread::spawn(move || {
        let read = frames::<RecordingError>(&path, |content, _| {
            Ok(match tx.send(Fed::Content(Box::new(content))) {
                Ok(()) => ControlFlow::Continue(()),
                Err(_) => ControlFlow::Break(()),
            })
        });
        // The receiver may be gone: nothing left to tell.
        let _ = tx.send(match read {
            Ok((_, truncated)) => Fed::End(truncated),
            Err(e) => Fed::Failed(e),
        });
    });
    ContentStream {
        rx,
        truncated: None,
        done: false,
    }
}

impl ContentStream {
    /// Why the file ended early, once the stream has ended (see
    /// [`RecordingReader::truncated`]).
    pub fn truncated(&self) -> Option<&str> {
        self.truncated.as_deref()
    }
}

impl Iterator for ContentStream {
    type Item = Result<Content, RecordingError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        match self.rx.recv() {
            Ok(Fed::Content(c)) => Some(Ok(*c)),
            Ok(Fed::Failed(e)) => {
                self.done = true;
                Some(Err(e))
            }
            Ok(Fed::End(truncated)) => {
                self.done = true;
                self.truncated = truncated;
                None
            }
            // The reading thread panicked: say so rather than end quietly.
            Err(_) => {
                self.done = true;
                Some(Err(RecordingError::Format {
                    path: PathBuf::new(),
                    message: "the reading thread stopped unexpectedly (a bug: please report it)"
                        .into(),
                }))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::fs::File;

    use super::*;

    /// A camera frame label (JSON, as `record` writes it).
    const LABEL: &[u8] = br#"{"sequence": 0, "timestamp_us": 0.0, "exposure_us": 1.0, "stamp_ref": "exposure_start", "label": "unresolved", "index": null, "phase": null, "trigger": null}"#;

    /// A file of frame labels whose images never come is refused once too many wait,
    /// instead of growing without bound.
    #[test]
    fn labels_without_images_are_bounded() {
        let path =
            std::env::temp_dir().join(format!("stereotac-labels-{}.mcap", std::process::id()));
        let file = std::io::BufWriter::new(File::create(&path).unwrap());
        let mut w = mcap::WriteOptions::new().create(file).unwrap();
        let topic = topics::camera_frame(0);
        let channel = w.add_channel(0, &topic, "json", &BTreeMap::new()).unwrap();
        for i in 0..(MAX_PENDING_LABELS as u64 + 10) {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i as u32,
                log_time: i,
                publish_time: i,
            };
            w.write_to_known_channel(&header, LABEL).unwrap();
        }
        w.finish().unwrap();
        drop(w);
        let mut frames_seen = 0;
        let result = frames::<RecordingError>(&path, |content, _| {
            if let Content::Frame(_) = content {
                frames_seen += 1;
            }
            Ok(ControlFlow::Continue(()))
        });
        let e = result.unwrap_err().to_string();
        assert!(e.contains("without their images"), "{e}");
        assert_eq!(frames_seen, 0);
        let _ = std::fs::remove_file(&path);
    }

    /// Frames whose labels were in a skipped chunk: their images are skipped and
    /// counted, and so are labels whose images were in it; every other frame is read;
    /// without a skipped chunk, an image with no label is an error.
    #[test]
    fn images_whose_labels_were_lost_are_skipped_and_counted() {
        use foxglove::Encode;
        let path = std::env::temp_dir().join(format!("stereotac-lost-{}.mcap", std::process::id()));
        let file = std::io::BufWriter::new(File::create(&path).unwrap());
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(2048))
            .create(file)
            .unwrap();
        let meta = BTreeMap::new();
        let labels = w
            .add_channel(0, &topics::camera_frame(0), "json", &meta)
            .unwrap();
        let images = w
            .add_channel(0, &topics::camera_image(0), "protobuf", &meta)
            .unwrap();
        let image = RgbImage::from_pixel(16, 16, image::Rgb([10, 20, 30]));
        let mut label_at = Vec::new();
        for i in 0..40u64 {
            let header = |channel_id| mcap::records::MessageHeader {
                channel_id,
                sequence: i as u32,
                log_time: i,
                publish_time: i,
            };
            w.write_to_known_channel(&header(labels), LABEL).unwrap();
            label_at.push(i);
            let mut raw = Vec::new();
            super::super::messages::rgb_image(&image, i, "cam0")
                .encode(&mut raw)
                .unwrap();
            // One chunk ends between each label and its image.
            w.flush().unwrap();
            w.write_to_known_channel(&header(images), &raw).unwrap();
        }
        w.finish().unwrap();
        drop(w);
        let read = |p: &Path| {
            let mut n = 0;
            let r = frames::<RecordingError>(p, |c, _| {
                n += usize::from(matches!(c, Content::Frame(_)));
                Ok(ControlFlow::Continue(()))
            });
            (n, r)
        };
        let (n, r) = read(&path);
        assert_eq!((n, r.unwrap().1), (40, None));
        // A byte of the label chunk of frame 20 (the label is its only message).
        let mut bytes = std::fs::read(&path).unwrap();
        let labels_at: Vec<usize> = bytes
            .windows(LABEL.len())
            .enumerate()
            .filter(|(_, w)| *w == LABEL)
            .map(|(i, _)| i)
            .collect();
        assert_eq!(labels_at.len(), 40);
        bytes[labels_at[20] + 10] ^= 0x10;
        std::fs::write(&path, &bytes).unwrap();
        let (n, r) = read(&path);
        let note = r.unwrap().1.expect("said");
        // That chunk held frame 19's image and frame 20's label: both frames lost.
        assert_eq!(n, 38, "{note}");
        assert!(note.contains("1 damaged chunk skipped"), "{note}");
        assert!(
            note.contains("1 image whose label was in a damaged chunk"),
            "{note}"
        );
        assert!(
            note.contains("1 frame label whose image never came"),
            "frame 19's label: {note}"
        );
        let _ = std::fs::remove_file(&path);
    }

    /// A label whose image never came is counted when the reading ends, and not when the
    /// caller broke off while it was waiting (its image may have been still to come).
    #[test]
    fn labels_without_images_are_counted_unless_the_reading_was_broken_off() {
        use foxglove::Encode;
        let path =
            std::env::temp_dir().join(format!("stereotac-waiting-{}.mcap", std::process::id()));
        let file = std::io::BufWriter::new(File::create(&path).unwrap());
        let mut w = mcap::WriteOptions::new().create(file).unwrap();
        let meta = BTreeMap::new();
        let labels = w
            .add_channel(0, &topics::camera_frame(0), "json", &meta)
            .unwrap();
        let images = w
            .add_channel(0, &topics::camera_image(0), "protobuf", &meta)
            .unwrap();
        let other = w.add_channel(0, topics::LED_PHASE, "json", &meta).unwrap();
        let header = |channel_id, t: u64| mcap::records::MessageHeader {
            channel_id,
            sequence: t as u32,
            log_time: t,
            publish_time: t,
        };
        let mut raw = Vec::new();
        let image = RgbImage::from_pixel(8, 8, image::Rgb([10, 20, 30]));
        super::super::messages::rgb_image(&image, 0, "cam0")
            .encode(&mut raw)
            .unwrap();
        // Frame 0: its label, another message, then its image; frame 1: a label only.
        w.write_to_known_channel(&header(labels, 0), LABEL).unwrap();
        w.write_to_known_channel(&header(other, 0), b"{}").unwrap();
        w.write_to_known_channel(&header(images, 0), &raw).unwrap();
        w.write_to_known_channel(&header(labels, 1), LABEL).unwrap();
        w.finish().unwrap();
        drop(w);
        let read = |stop_at_other: bool| {
            let mut n = 0;
            let (_, note) = frames::<RecordingError>(&path, |c, _| {
                n += usize::from(matches!(c, Content::Frame(_)));
                let stop = stop_at_other && matches!(c, Content::Other(_));
                Ok(if stop {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                })
            })
            .unwrap();
            (n, note.unwrap_or_default())
        };
        let (n, note) = read(false);
        assert_eq!(n, 1);
        assert!(
            note.contains("1 frame label whose image never came"),
            "frame 1's label: {note:?}"
        );
        // Broken off at the message between frame 0's label and its image.
        let (n, note) = read(true);
        assert_eq!((n, note.as_str()), (0, ""));
        let _ = std::fs::remove_file(&path);
    }

    /// A recording of `n` JSON messages on the LED phase topic, log times 0..n.
    fn json_recording(name: &str, n: u64) -> PathBuf {
        json_recording_with(name, n, mcap::WriteOptions::new())
    }

    /// [`json_recording`] written with `options`.
    fn json_recording_with(name: &str, n: u64, options: mcap::WriteOptions) -> PathBuf {
        let path =
            std::env::temp_dir().join(format!("stereotac-{name}-{}.mcap", std::process::id()));
        let file = std::io::BufWriter::new(File::create(&path).unwrap());
        let mut w = options.create(file).unwrap();
        let channel = w
            .add_channel(0, topics::LED_PHASE, "json", &BTreeMap::new())
            .unwrap();
        for i in 0..n {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i as u32,
                log_time: i,
                publish_time: i,
            };
            w.write_to_known_channel(&header, format!("{{\"i\": {i}}}").as_bytes())
                .unwrap();
        }
        w.finish().unwrap();
        path
    }

    /// The stream gives what `frames` gives, in order; a missing file is its first item;
    /// a file cut short ends the stream and says so.
    #[test]
    fn stream_pulls_in_file_order() {
        let path = json_recording("stream", 50);
        let times: Vec<u64> = stream(&path, 4)
            .map(|c| match c.unwrap() {
                Content::Other(Record::Message { log_time_ns, .. }) => log_time_ns,
                other => panic!("unexpected {other:?}"),
            })
            .collect();
        assert_eq!(times, (0..50).collect::<Vec<_>>());
        // Dropped after two items: the reading thread stops (the test would hang on a
        // full channel otherwise only if the thread blocked forever; it must not).
        let mut s = stream(&path, 1);
        assert!(s.next().unwrap().is_ok());
        drop(s);
        // Uncompressed, in chunks of 4 kB (a chunk is read whole, its checksum checked,
        // before any of its messages is handed out; a flipped byte fails the checksum
        // rather than the decompression).
        let options = || {
            mcap::WriteOptions::new()
                .compression(None)
                .chunk_size(Some(4096))
        };
        let chunked = json_recording_with("chunked", 2000, options());
        let bytes = std::fs::read(&chunked).unwrap();
        let cut = path.with_extension("cut.mcap");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let mut s = stream(&cut, 4);
        assert!(s.by_ref().map(Result::unwrap).count() > 0);
        assert!(s.truncated().is_some(), "a cut file is reported");
        // Cut before any message, or empty: an error, not a warning.
        for end in [0, 8, 40] {
            std::fs::write(&cut, &bytes[..end]).unwrap();
            let e = stream(&cut, 4).find_map(Result::err).expect("refused");
            assert!(e.to_string().contains("holds no message"), "{end}: {e}");
        }
        let _ = std::fs::remove_file(chunked);
        // A damaged chunk: skipped whole, the damage said, and the chunks after it read.
        let damaged = json_recording_with("damaged", 2000, options());
        let mut bytes = std::fs::read(&damaged).unwrap();
        let middle = bytes.len() / 2;
        bytes[middle] ^= 0x10;
        std::fs::write(&damaged, &bytes).unwrap();
        let read_times = |path: &Path| {
            let mut s = stream(path, 4);
            let times: Vec<u64> = s
                .by_ref()
                .map(|c| match c.unwrap() {
                    Content::Other(Record::Message { log_time_ns, .. }) => log_time_ns,
                    other => panic!("unexpected {other:?}"),
                })
                .collect();
            (times, s.truncated().map(str::to_string))
        };
        let (times, note) = read_times(&damaged);
        let note = note.expect("the damage is said");
        assert!(
            note.contains("Chunk CRC") && note.contains("1 damaged chunk skipped"),
            "{note}"
        );
        // In order, one gap: the damaged chunk's messages, none of them handed out (the
        // first one missing lies before the damage; checked after its records, the chunk
        // would have handed them all out), and every message after the chunk read.
        assert!(times.windows(2).all(|w| w[0] < w[1]));
        let gap = times
            .windows(2)
            .position(|w| w[1] != w[0] + 1)
            .expect("a gap");
        let (first_lost, first_after) = (times[gap] + 1, times[gap + 1]);
        assert_eq!(times[0], 0);
        assert_eq!(*times.last().unwrap(), 1999);
        assert!(first_after - first_lost < 200, "one 4 kB chunk lost");
        let place = |i: u64| {
            let text = format!("{{\"i\": {i}}}");
            bytes
                .windows(text.len())
                .position(|w| w == text.as_bytes())
                .expect("in the file")
        };
        assert!(place(first_lost) < middle && middle < place(first_after));
        // The first chunk damaged (it declares the channel): the summary names it, and
        // the rest is read; the summary itself damaged: every message read, and said.
        let mut first = std::fs::read(&damaged).unwrap();
        first[middle] ^= 0x10;
        first[200] ^= 0x10;
        std::fs::write(&damaged, &first).unwrap();
        let (times, note) = read_times(&damaged);
        assert!(times.len() > 1500 && times[0] > 0, "{}", times.len());
        assert!(note.unwrap().contains("1 damaged chunk skipped"));
        let mut summary = std::fs::read(&damaged).unwrap();
        summary[200] ^= 0x10;
        // The topic's length field in the summary's channel record, beyond the record.
        let topic = topics::LED_PHASE.as_bytes();
        let last = summary
            .windows(topic.len())
            .rposition(|w| w == topic)
            .expect("the summary repeats the channel");
        summary[last - 4..last].copy_from_slice(&u32::MAX.to_le_bytes());
        std::fs::write(&damaged, &summary).unwrap();
        let (times, note) = read_times(&damaged);
        assert_eq!(times, (0..2000).collect::<Vec<_>>());
        let note = note.unwrap_or_default();
        assert!(note.contains("summary section"), "{note}");
        // A chunk's length field damaged (one less, or 4096 more): where the chunk ends
        // cannot be trusted, so the reading goes on at the next chunk the summary indexes
        // (it was an error, and the pairs before were lost); without a summary, it stops
        // there with a note, keeping what came before.
        let mut walk = 8usize;
        let mut chunks = Vec::new();
        while walk + 9 <= bytes.len() && bytes[walk] != mcap::records::op::FOOTER {
            if bytes[walk] == mcap::records::op::CHUNK {
                chunks.push(walk);
            }
            let len = u64::from_le_bytes(bytes[walk + 1..walk + 9].try_into().unwrap());
            walk += 9 + len as usize;
        }
        assert!(chunks.len() > 10, "{} chunks", chunks.len());
        let fresh = json_recording_with("length", 2000, options());
        let whole = std::fs::read(&fresh).unwrap();
        let _ = std::fs::remove_file(fresh);
        for change in [-1i64, 4096, 1 << 40] {
            let mut broken = whole.clone();
            let at = chunks[chunks.len() / 2] + 1;
            let len = u64::from_le_bytes(broken[at..at + 8].try_into().unwrap());
            let len = len.wrapping_add_signed(change);
            broken[at..at + 8].copy_from_slice(&len.to_le_bytes());
            std::fs::write(&damaged, &broken).unwrap();
            let (times, note) = read_times(&damaged);
            let note = note.expect("said");
            assert!(
                note.contains("1 damaged chunk skipped"),
                "change {change}: {note}"
            );
            assert!(times.windows(2).all(|w| w[0] < w[1]));
            // One less: the chunk's records were whole and all read before its end was
            // found wrong; 4096 more: the next chunk was swallowed as padding without an
            // error, and is read again from the summary's index; past the file's end.
            assert!(times.len() > 1700, "change {change}: {}", times.len());
            assert_eq!((times[0], times[times.len() - 1]), (0, 1999));
            // No summary (the footer points at none): the reading stops there.
            let footer = broken.len() - 8 - 29;
            assert_eq!(broken[footer], mcap::records::op::FOOTER);
            broken[footer + 9..footer + 17].fill(0);
            std::fs::write(&damaged, &broken).unwrap();
            let (times, note) = read_times(&damaged);
            let note = note.expect("said");
            assert!(note.contains("damaged at byte"), "change {change}: {note}");
            let read = times.len() as u64;
            assert!(read > 500 && read < 2000, "change {change}: {read}");
            assert_eq!(times, (0..read).collect::<Vec<_>>());
        }
        let _ = std::fs::remove_file(damaged);
        // Two recordings one after the other: the first is read whole, and the bytes
        // after it are said (`cat` of two files was read as the first with no word).
        let whole = std::fs::read(&path).unwrap();
        let twice = path.with_extension("twice.mcap");
        std::fs::write(&twice, [whole.as_slice(), whole.as_slice()].concat()).unwrap();
        let mut s = stream(&twice, 4);
        assert_eq!(s.by_ref().map(Result::unwrap).count(), 50);
        let note = s.truncated().expect("the appended file is said");
        assert!(note.contains("were not read"), "{note}");
        let mut s = stream(&path, 4);
        assert_eq!(s.by_ref().count(), 50);
        assert_eq!(s.truncated(), None, "a whole file has no note");
        let _ = std::fs::remove_file(twice);
        let e = stream(&path.with_extension("missing.mcap"), 4)
            .next()
            .unwrap()
            .unwrap_err();
        assert!(matches!(e, RecordingError::Io { .. }), "{e}");
        for p in [path, cut] {
            let _ = std::fs::remove_file(p);
        }
    }
}
