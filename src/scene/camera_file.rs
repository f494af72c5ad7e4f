//! Camera files: one camera per frame, the form an animation package exports (the scene TOML's
//! `camera = "shot.json"`; docs/camera.md has the formats, `scripts/blender/export_camera.py`
//! writes one). Not keyframes: every frame of the scene is given, once, in order, and nothing
//! is interpolated.
//!
//! JSON: `{"frames": [{"frame": 0, "fov": 40.0, "matrix": [16 numbers]}, ...]}`, each entry with
//! either `matrix` (camera-to-world, row-major) or `position`, `look_at` and `up`. CSV: a header
//! `frame,fov,m00,m01,...,m33` or `frame,fov,px,py,pz,lx,ly,lz,ux,uy,uz`, then one row per frame.
//!
//! Numbers that become the camera's f32 coordinates are parsed from their text as f32 (JSON
//! numbers through `RawValue`): serde_json reads numbers as f64, and decimal to f64 to f32 can
//! round twice, so a file written from a render's own f32 cameras (`{}` prints the shortest
//! text that reads back) could come back one bit off. Matrices are read in f64, checked, and
//! turned into a pose there (`Pose::from_camera_to_world`), with the eye, their translation,
//! read as f32 like any coordinate.
//!
//! Every refusal is one line naming the file, the line and the frame (for JSON also the entry).
use super::repairs::{Kind, Repairs};
use super::text::{fov_fault, line_at, past_max_coord, quote, Lines, MAX_COORD};
use crate::camera::Pose;
use crate::util::text::plain_types;
use anyhow::{anyhow, bail, Result};
use glam::DVec3;
use serde::Deserialize;
use serde_json::value::RawValue;

/// The two forms of camera file, by the file name's extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Json,
    Csv,
}

impl Format {
    /// The format of a file named `name` (`.json` or `.csv`, in any case).
    pub fn of(name: &str) -> Option<Format> {
        let ext = std::path::Path::new(name).extension()?.to_str()?;
        if ext.eq_ignore_ascii_case("json") {
            Some(Format::Json)
        } else if ext.eq_ignore_ascii_case("csv") {
            Some(Format::Csv)
        } else {
            None
        }
    }
}

/// The camera of one frame as the file gives it, before the checks.
enum Form {
    /// Camera-to-world, row-major, and its translation read as f32 (the eye).
    Matrix([f64; 16], [f32; 3]),
    LookAt {
        position: [f32; 3],
        look_at: [f32; 3],
        up: [f32; 3],
        /// Position and look-at read in f64 too, for a scene moved to its origin.
        exact: [[f64; 3]; 2],
    },
}

/// One entry (JSON) or row (CSV): where it is, for messages, and what it says.
struct Entry {
    /// "line 7" (CSV) or "line 7 (entry 3)" (JSON).
    at: String,
    /// The line the entry starts on (for repair warnings).
    line: usize,
    frame: u32,
    /// As read (`text::fov_fault` checks it before it becomes the pose's f32).
    fov: f64,
    form: Form,
}

/// The poses of frames `0..frames` from the camera file `label` (its bytes, in `format`).
#[cfg(test)]
pub fn parse(
    label: &str,
    bytes: &[u8],
    format: Format,
    frames: u32,
    repairs: &mut Repairs,
) -> Result<Vec<Pose>> {
    parse_from(label, bytes, format, frames, repairs, DVec3::ZERO)
}

/// The poses of frames `0..frames` from the camera file `label` (its bytes, in `format`), with
/// every eye given from `origin` (`Scene::origin`): subtracted in f64 from the
/// file's numbers before they are rounded to f32, so that a camera far from the origin keeps
/// its place to the file's precision (f32 rounds to half a unit at 5x10^6).
pub fn parse_from(
    label: &str,
    bytes: &[u8],
    format: Format,
    frames: u32,
    repairs: &mut Repairs,
    origin: DVec3,
) -> Result<Vec<Pose>> {
    let text = super::text::as_text(bytes).map_err(|e| anyhow!("{label}: {e}"))?;
    // A byte order mark, as spreadsheets write it, is not part of the first line.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    if text.trim().is_empty() {
        bail!("{label}: the file is empty");
    }
    let entries = match format {
        Format::Json => json_entries(label, text)?,
        Format::Csv => csv_entries(label, text, repairs)?,
    };
    let mut poses: Vec<Pose> = Vec::with_capacity(entries.len());
    for (i, e) in entries.iter().enumerate() {
        let at = format!("{label}: {}: frame {}", e.at, e.frame);
        let want = i as u32;
        if e.frame != want {
            // Entries 0..i are frames 0..i: a smaller frame is one of them again.
            let later = || entries[i + 1..].iter().find(|l| l.frame == want);
            let why = if e.frame < want {
                format!("given twice (also at {})", entries[e.frame as usize].at)
            } else if e.frame >= frames && i == 0 {
                // An animation package's frame numbers (Blender starts at 1, many studios at
                // 1001): the file's first frame is the scene's frame 0.
                format!(
                    "past the last frame ({}): a camera file numbers the scene's frames from 0 \
                     (renumber the file's frames {}, {}, ... as 0, 1, ...)",
                    frames - 1,
                    e.frame,
                    e.frame + 1
                )
            } else if e.frame >= frames {
                format!("past the last frame ({})", frames - 1)
            } else if let Some(l) = later() {
                format!("out of order: frame {want} comes after it, at {}", l.at)
            } else if i == 0 {
                // Blender's first frame is 1: numbered from there, within the scene's frames.
                format!(
                    "frame 0 is missing: a camera file numbers the scene's frames from 0 \
                     (renumber the file's frames {}, {}, ... as 0, 1, ...)",
                    e.frame,
                    e.frame + 1
                )
            } else {
                format!(
                    "frame {want} is missing (a camera file gives every frame 0, 1, 2, ... in \
                     order)"
                )
            };
            bail!("{at}: {why}");
        }
        if e.frame >= frames {
            bail!(
                "{at}: past the last frame ({}): the scene has {frames} frames",
                frames - 1
            );
        }
        poses.push(pose(e, origin).map_err(|why| anyhow!("{at}: {why}"))?);
        if let Form::Matrix(m, _) = &e.form {
            let shear = shear_degrees(m);
            if shear > MAX_SHEAR_DEGREES {
                repairs.note(label, e.line, SHEARED, || {
                    format!(
                        "frame {}: the matrix's axes are {shear:.2} degrees from perpendicular",
                        e.frame
                    )
                })?;
            }
        }
    }
    if let Some(largest) = fovs_look_like_radians(entries.iter().map(|e| e.fov)) {
        repairs.note(label, entries[0].line, FOV_RADIANS, || {
            format!("the largest of its fovs is {largest}")
        })?;
    }
    let n = poses.len() as u32;
    if n < frames {
        let last = entries.last().map_or(String::new(), |e| {
            format!(" (the last entry, frame {}, is at {})", e.frame, e.at)
        });
        bail!(
            "{label}: frame {n} is missing: the scene has {frames} frames, the file gives \
             {n}{last}"
        );
    }
    Ok(poses)
}

/// The checked pose of an entry (its eye given from `origin`), or why it is refused.
fn pose(e: &Entry, origin: DVec3) -> Result<Pose, String> {
    if let Some(why) = fov_fault(e.fov) {
        return Err(why);
    }
    let fov = e.fov as f32;
    let pose = match &e.form {
        Form::LookAt {
            position,
            look_at,
            up,
            exact,
        } => {
            for (key, c) in [("position", position), ("look_at", look_at), ("up", up)] {
                if !c.iter().all(|c| c.is_finite()) {
                    let why = super::text::beyond_f32(c.iter().copied());
                    return Err(format!("{key} {c:?} is not finite{why}"));
                }
                if c.iter().any(|c| c.abs() > MAX_COORD) {
                    return Err(format!("{key} {c:?} is too large (at most {MAX_COORD:e})"));
                }
            }
            let (position, look_at) = (glam::Vec3::from(*position), glam::Vec3::from(*look_at));
            let (eye, view) = if origin == DVec3::ZERO {
                (position, look_at - position)
            } else {
                let [p, l] = exact.map(DVec3::from);
                ((p - origin).as_vec3(), (l - p).as_vec3())
            };
            Pose {
                eye,
                view,
                up: glam::Vec3::from(*up),
                fov,
            }
        }
        Form::Matrix(m, eye) => {
            check_matrix(m)?;
            let eye = if origin == DVec3::ZERO {
                glam::Vec3::from(*eye)
            } else {
                (DVec3::new(m[3], m[7], m[11]) - origin).as_vec3()
            };
            Pose {
                eye,
                ..Pose::from_camera_to_world(m, fov)
            }
        }
    };
    match pose.fault() {
        Some(why) => Err(why),
        None => Ok(pose),
    }
}

/// Smallest volume of the parallelepiped of the 3x3 part's unit columns: below it, two axes
/// are nearly parallel (the sine of their angle is at most this), or all three in a plane.
const MIN_UNIT_VOLUME: f64 = 1e-4;

/// Refuse a camera-to-world matrix that is not finite, too large, not affine, or whose 3x3 part
/// is singular, nearly so, or mirrored.
fn check_matrix(m: &[f64; 16]) -> Result<(), String> {
    let name = |i: usize| format!("m{}{}", i / 4, i % 4);
    for (i, v) in m.iter().enumerate() {
        if !v.is_finite() {
            return Err(format!("matrix element {} = {v} is not finite", name(i)));
        }
        if past_max_coord(*v) {
            return Err(format!(
                "matrix element {} = {v:e} is too large (at most {MAX_COORD:e})",
                name(i)
            ));
        }
    }
    if m[12..] != [0.0, 0.0, 0.0, 1.0] {
        // Written column by column (as OpenGL and some exporters hold matrices), the
        // translation is the bottom row and the last column is [0, 0, 0, 1].
        let transposed = [m[3], m[7], m[11], m[15]] == [0.0, 0.0, 0.0, 1.0];
        return Err(format!(
            "matrix bottom row {:?} is not [0, 0, 0, 1] (a camera-to-world matrix is affine){}",
            &m[12..],
            if transposed {
                "; its last column is [0, 0, 0, 1]: it looks written column by column, and the \
                 file's matrices are row-major (transpose them)"
            } else {
                ""
            }
        ));
    }
    let col = |c: usize| glam::DVec3::new(m[c], m[4 + c], m[8 + c]);
    let (x, y, z) = (col(0), col(1), col(2));
    let det = x.dot(y.cross(z));
    // Scale drops out: the volume of the unit columns measures how far from parallel they are.
    // Each column is made unit on its own (divided by its largest element first), so that a
    // rotation scaled by 1e-110, whose determinant and length product underflow, is a rotation.
    let unit = crate::camera::direction;
    let volume = match (unit(x), unit(y), unit(z)) {
        (Some(x), Some(y), Some(z)) => x.dot(y.cross(z)),
        _ => 0.0,
    };
    if volume.abs() <= MIN_UNIT_VOLUME {
        return Err(format!(
            "matrix is singular or nearly so (determinant of its 3x3 part {det:e}): its axes are \
             (nearly) parallel or zero"
        ));
    }
    if volume < 0.0 {
        return Err(format!(
            "matrix is mirrored (determinant of its 3x3 part {det:e} < 0): a camera's axes are \
             right-handed"
        ));
    }
    Ok(())
}

/// A camera-to-world matrix whose axes are further than this from perpendicular is noted as
/// repaired (`SHEARED`): an exporter's rounding leaves thousandths of a degree, while a camera
/// parented to a non-uniformly scaled, rotated object is sheared by whole degrees, and its
/// image is then not the one `Pose::from_camera_to_world` makes (view kept, up made
/// perpendicular to it, right perpendicular to both).
pub const MAX_SHEAR_DEGREES: f64 = 0.1;

/// A number like `1.000` in a file separated by semicolons or tabs, whose locale may group
/// thousands with a point.
const POINT_MAY_GROUP: Kind = Kind {
    one: "a number with three digits after its point, in a file separated by semicolons or \
          tabs, read as a decimal ('1.000' is 1): where the locale groups thousands with a point \
          it means 1000 (write such a file with decimal commas, or without grouping)",
    many: "numbers with three digits after their point, in a file separated by semicolons or \
           tabs, read as decimals ('1.000' is 1): where the locale groups thousands with a \
           point they mean 1000 (write such a file with decimal commas, or without grouping)",
};

/// Whether `f` reads as a thousands-grouped integer too: 1 to 3 digits, not starting with 0,
/// a point, then exactly three digits (`1.000`, `-12.500`).
fn may_group_thousands(f: &str) -> bool {
    let f = f.trim();
    let f = f.strip_prefix(['-', '+']).unwrap_or(f);
    let Some((int, frac)) = f.split_once('.') else {
        return false;
    };
    let digits = |s: &str| s.bytes().all(|b| b.is_ascii_digit());
    (1..=3).contains(&int.len())
        && !int.starts_with('0')
        && digits(int)
        && frac.len() == 3
        && digits(frac)
}

/// A camera whose every fov is below pi: likely radians (Blender's `camera.data.angle`, most
/// scripting APIs), which read as degrees give a telephoto view 57 times narrower.
pub(crate) const FOV_RADIANS: Kind = Kind {
    one: "every fov is below pi: read as degrees (if they are radians, as Blender's and most \
          scripting APIs' camera angles are, multiply them by 180/pi)",
    many: "cameras whose every fov is below pi: read as degrees (if they are radians, as \
           Blender's and most scripting APIs' camera angles are, multiply them by 180/pi)",
};

/// Whether `fovs` (degrees, as given) look like radians: there are some, and every one is
/// below pi (a lens that narrow throughout is a 600 mm telephoto or longer).
pub(crate) fn fovs_look_like_radians(fovs: impl IntoIterator<Item = f64>) -> Option<f64> {
    let largest = fovs.into_iter().reduce(f64::max)?;
    (largest < std::f64::consts::PI).then_some(largest)
}

const SHEARED: Kind = Kind {
    one: "sheared camera made rigid (view kept, up made perpendicular to it)",
    many: "sheared cameras made rigid (view kept, up made perpendicular to it)",
};

/// How far the axes of a matrix's 3x3 part are from perpendicular: the largest of the three
/// pairs' departures from 90 degrees (scale does not count; `check_matrix` has refused zero
/// and parallel axes).
fn shear_degrees(m: &[f64; 16]) -> f64 {
    let col = |c: usize| {
        crate::camera::direction(glam::DVec3::new(m[c], m[4 + c], m[8 + c]))
            .unwrap_or(glam::DVec3::ZERO)
    };
    let (x, y, z) = (col(0), col(1), col(2));
    [(x, y), (y, z), (z, x)]
        .into_iter()
        .map(|(a, b)| (90.0 - a.dot(b).clamp(-1.0, 1.0).acos().to_degrees()).abs())
        .fold(0.0, f64::max)
}

/// A JSON number as written (any JSON value, refused later if not a number).
struct Num<'a>(&'a str);

impl<'de: 'a, 'a> Deserialize<'de> for Num<'a> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        <&RawValue>::deserialize(d).map(|r| Num(r.get()))
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonFile<'a> {
    #[serde(borrow)]
    frames: Vec<&'a RawValue>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonEntry<'a> {
    #[serde(borrow)]
    frame: Num<'a>,
    #[serde(borrow)]
    fov: Num<'a>,
    #[serde(borrow)]
    matrix: Option<Vec<Num<'a>>>,
    #[serde(borrow)]
    position: Option<Vec<Num<'a>>>,
    #[serde(borrow)]
    look_at: Option<Vec<Num<'a>>>,
    #[serde(borrow)]
    up: Option<Vec<Num<'a>>>,
}

/// A camera file's frame `text` at `at` (a line, an entry) that `frame_number` refused.
fn not_a_frame(label: &str, at: &str, text: &str) -> anyhow::Error {
    anyhow!(
        "{label}: {at}: frame '{}' is not a frame number (a whole number from 0 to 4294967295)",
        quote(text)
    )
}

/// serde_json's message without its " at line L column C" (the caller names the line), in
/// JSON's words (`plain_types`: no Rust type names).
fn json_message(e: &serde_json::Error) -> String {
    let m = e.to_string();
    let m = match m.rfind(" at line ") {
        Some(i) => &m[..i],
        None => &m,
    };
    plain_types(m, "an object")
}

/// A matrix's numbers, row-major: as given, or its four rows of four (`[[...], ...]`, as numpy's
/// `tolist()` writes a 4x4 matrix) one after the other.
fn matrix_rows<'a>(m: &[Num<'a>]) -> Result<Vec<Num<'a>>, String> {
    if !m.iter().any(|n| n.0.trim_start().starts_with('[')) {
        return Ok(m.iter().map(|n| Num(n.0)).collect());
    }
    let rows: Option<Vec<Vec<Num<'a>>>> = m
        .iter()
        .map(|n| serde_json::from_str::<Vec<Num<'a>>>(n.0).ok())
        .collect();
    match rows {
        Some(rows) if rows.len() == 4 && rows.iter().all(|r| r.len() == 4) => {
            Ok(rows.into_iter().flatten().collect())
        }
        _ => Err(format!(
            "matrix is given as {} row{}{}: give 16 numbers, row-major, or 4 rows of 4",
            m.len(),
            if m.len() == 1 { "" } else { "s" },
            rows_shape(m)
        )),
    }
}

/// " of 4, 3, ..." numbers for a matrix given as rows, for a message.
fn rows_shape(m: &[Num]) -> String {
    let sizes: Vec<String> = m
        .iter()
        .map(|n| {
            serde_json::from_str::<Vec<&RawValue>>(n.0)
                .map_or("1".to_string(), |r| r.len().to_string())
        })
        .collect();
    format!(" of {} numbers", sizes.join(", "))
}

/// `N` numbers of `key`, parsed as `T` from their text.
fn numbers<T: std::str::FromStr + Default + Copy, const N: usize>(
    key: &str,
    v: &[Num],
) -> Result<[T; N], String> {
    if v.len() != N {
        return Err(format!("{key} has {} numbers, not {N}", v.len()));
    }
    let mut out = [T::default(); N];
    for (o, n) in out.iter_mut().zip(v) {
        *o = number(key, n.0)?;
    }
    Ok(out)
}

/// The translation (elements 3, 7 and 11) of a matrix whose element `i` is `text(i)`, read as
/// f32 from the text (as every coordinate: see the module note), `name(i)` in messages.
fn translation<'a>(
    text: impl Fn(usize) -> &'a str,
    name: impl Fn(usize) -> String,
) -> Result<[f32; 3], String> {
    let mut eye = [0.0f32; 3];
    for (r, e) in eye.iter_mut().enumerate() {
        *e = number(&name(4 * r + 3), text(4 * r + 3))?;
    }
    Ok(eye)
}

fn number<T: std::str::FromStr>(key: &str, text: &str) -> Result<T, String> {
    // Rust also reads `inf` and `NaN`, which are not JSON numbers (JSON parsing refused those
    // already; a CSV's are refused as not finite, naming the column).
    text.trim()
        .parse()
        .map_err(|_| format!("{key} '{}' is not a number", quote(text)))
}

fn json_entries(label: &str, text: &str) -> Result<Vec<Entry>> {
    // Lines ended by a bare CR (a classic Mac editor's) are counted as lines: CR and LF are both
    // white space to JSON, so each bare CR read as an LF changes nothing but the line numbers,
    // which serde counts by LF alone (an error on the last line was said to be on line 1).
    let with_lf;
    let text = if text.contains('\r') {
        let mut b = text.as_bytes().to_vec();
        for i in 0..b.len() {
            if b[i] == b'\r' && b.get(i + 1) != Some(&b'\n') {
                b[i] = b'\n';
            }
        }
        // One ASCII byte for another: still UTF-8.
        with_lf = String::from_utf8(b).expect("ASCII for ASCII");
        with_lf.as_str()
    } else {
        text
    };
    // serde would read an array as the struct's fields in order, and complain about the first.
    if text.trim_start().starts_with('[') {
        bail!(
            "{label}: line {}: the file is an array: a camera file is an object, \
             {{\"frames\": [...]}}",
            line_at(text.as_bytes(), text.len() - text.trim_start().len())
        );
    }
    let file: JsonFile = serde_json::from_str(text).map_err(|e| {
        let at_line = text.lines().nth(e.line().saturating_sub(1)).unwrap_or("");
        // Python's json module writes NaN and Infinity, which JSON does not have: say so.
        let here = at_line.get(e.column().saturating_sub(1)..).unwrap_or("");
        let here = here.trim_start_matches(['-', '+']);
        let hint = if ["NaN", "nan", "Infinity", "inf"]
            .iter()
            .any(|w| here.starts_with(w))
        {
            " (NaN or Infinity: a camera's numbers must be finite, and JSON has no such numbers)"
        } else if here.starts_with("//") || here.starts_with("/*") {
            // A comment, as a JSON5 or JavaScript exporter writes one.
            " (a comment: JSON has none; remove it)"
        } else {
            ""
        };
        // A file written on one line (Python's `json.dump`) says where on it, too.
        let column = if at_line.len() > 120 {
            format!(", column {}", e.column())
        } else {
            String::new()
        };
        anyhow!(
            "{label}: line {}{column}: {}{hint}",
            e.line(),
            json_message(&e)
        )
    })?;
    let mut entries = Vec::with_capacity(file.frames.len());
    let lines = Lines::new(text.as_bytes());
    for (i, raw) in file.frames.iter().enumerate() {
        // The entry's place in the file: `raw` borrows from `text`.
        let offset = raw.get().as_ptr() as usize - text.as_ptr() as usize;
        let line = lines.at(offset);
        let at = format!("line {line} (entry {})", i + 1);
        // serde would read an array as the entry's fields in order (`[0, 45.0, [...]]` taken
        // for frame, fov and matrix): an entry is an object.
        if !raw.get().starts_with('{') {
            let what = match raw.get().as_bytes()[0] {
                b'[' => "an array",
                b'"' => "a string",
                b'n' => "null",
                b't' | b'f' => "a boolean",
                _ => "a number",
            };
            bail!(
                "{label}: {at}: the entry is {what}: each entry is an object, {{\"frame\": 0, \
                 \"fov\": 50.0, \"matrix\": [16 numbers]}} or with \"position\", \"look_at\" \
                 and \"up\" in place of \"matrix\""
            );
        }
        let e: JsonEntry = serde_json::from_str(raw.get()).map_err(|e| {
            anyhow!(
                "{label}: line {} (entry {}): {}",
                line + e.line() - 1,
                i + 1,
                json_message(&e)
            )
        })?;
        let frame = frame_number(e.frame.0).ok_or_else(|| not_a_frame(label, &at, e.frame.0))?;
        let form = (|| match (&e.matrix, &e.position, &e.look_at, &e.up) {
            (Some(m), None, None, None) => {
                let m = matrix_rows(m)?;
                Ok(Form::Matrix(
                    numbers("matrix", &m)?,
                    translation(
                        |i| m[i].0,
                        |i| format!("matrix element m{}{}", i / 4, i % 4),
                    )?,
                ))
            }
            (None, Some(p), Some(l), Some(u)) => Ok(Form::LookAt {
                position: numbers("position", p)?,
                look_at: numbers("look_at", l)?,
                up: numbers("up", u)?,
                exact: [numbers("position", p)?, numbers("look_at", l)?],
            }),
            (Some(_), ..) => Err("both matrix and position/look_at/up: give one".to_string()),
            _ => Err("needs matrix, or position, look_at and up".to_string()),
        })();
        let fov = number("fov", e.fov.0);
        let (form, fov) = match (form, fov) {
            (Ok(f), Ok(v)) => (f, v),
            (Err(why), _) | (_, Err(why)) => {
                bail!("{label}: {at}: frame {frame}: {why}")
            }
        };
        entries.push(Entry {
            at,
            line,
            frame,
            fov,
            form,
        });
    }
    Ok(entries)
}

/// A frame number as a file writes it: a whole number from 0, as an integer or as a number
/// whose value is one (`0.0`, `1e0`, `0.000000000000000000e+00`: a frame column that went
/// through floating point, as numpy's `savetxt` and `tolist()` write it).
fn frame_number(text: &str) -> Option<u32> {
    if let Ok(n) = text.parse::<u32>() {
        return Some(n);
    }
    // Digits with a point and an exponent, whole as written: every digit past the point's
    // place after the exponent moves it is a zero (`1e-400` and `0.99999999999999999` are not
    // frames, though they read as the floats 0 and 1).
    let unsigned = text.strip_prefix('+').unwrap_or(text);
    // A minus before nothing but zeros is zero (`-0`, `-0.0`, as numpy writes a negative zero).
    let unsigned = match unsigned.strip_prefix('-') {
        Some(rest) if rest.bytes().all(|b| matches!(b, b'0' | b'.')) && rest.contains('0') => "0",
        _ => unsigned,
    };
    let (mantissa, exponent) = match unsigned.split_once(['e', 'E']) {
        Some((m, e)) => (m, e.parse::<i32>().ok()?),
        None => (unsigned, 0),
    };
    let (int, frac) = mantissa.split_once('.').unwrap_or((mantissa, ""));
    let digits = format!("{int}{frac}");
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let point = int.len() as i64 + exponent as i64;
    let whole = digits
        .bytes()
        .enumerate()
        .all(|(i, b)| (i as i64) < point || b == b'0');
    let x: f64 = unsigned.parse().ok()?;
    (whole && x <= u32::MAX as f64).then_some(x as u32)
}

/// The CSV headers, one per form.
fn matrix_header() -> Vec<String> {
    let mut h = vec!["frame".to_string(), "fov".to_string()];
    h.extend((0..16).map(|i| format!("m{}{}", i / 4, i % 4)));
    h
}

const LOOK_AT_HEADER: [&str; 11] = [
    "frame", "fov", "px", "py", "pz", "lx", "ly", "lz", "ux", "uy", "uz",
];

/// The fields of a CSV line separated by `sep`, as RFC 4180 writes them (a field in double
/// quotes may hold the separator, and `""` is a quote: R's `write.csv`, pandas' quoting),
/// trimmed, each with whether it was quoted. `Err` where a quote is not closed on its line (a
/// camera file's field holds no line break): the line was cut short, or a quote added by hand.
fn csv_fields(line: &str, sep: char) -> Result<Vec<(String, bool)>, String> {
    let mut fields = vec![(String::new(), false)];
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        let field = fields.last_mut().expect("one field at least");
        match c {
            '"' if quoted && chars.peek() == Some(&'"') => {
                chars.next();
                field.0.push('"');
            }
            '"' => {
                quoted = !quoted;
                field.1 = true;
            }
            c if c == sep && !quoted => fields.push((String::new(), false)),
            c => field.0.push(c),
        }
    }
    if quoted {
        return Err(format!(
            "the quote opened in '{}' is not closed on the line (cut short?)",
            quote(line.trim())
        ));
    }
    for f in &mut fields {
        f.0 = f.0.trim().to_string();
    }
    Ok(fields)
}

/// A field with a number's decimal comma read as a point: any in a file separated by
/// semicolons or tabs (a spreadsheet in a German or French locale), and one in quotes in a file
/// separated by commas unless three digits follow its comma (`"1,000"` may group thousands).
fn decimal_point((f, quoted): (String, bool), sep: char) -> String {
    let decimal = f.split_once(',').filter(|(_, frac)| {
        !f.contains('.') && !frac.contains(',') && (sep != ',' || (quoted && frac.len() != 3))
    });
    match decimal {
        Some((int, frac)) if format!("{int}.{frac}").parse::<f64>().is_ok() => {
            format!("{int}.{frac}")
        }
        _ => f,
    }
}

/// A CSV header line (without a comment's `#`): its separator as spreadsheets write it (a comma,
/// or a semicolon where the locale's decimal mark is a comma, as German or French Excel and
/// LibreOffice write it, or a tab), and its column names in lower case; a separator at its end
/// (an empty last name: a column of nothing) is left out of the names.
fn csv_header(text: &str) -> (char, Vec<String>) {
    let sep = [',', ';', '\t']
        .into_iter()
        .find(|c| text.contains(*c))
        .unwrap_or(',');
    // A header with an unclosed quote names no columns, and is refused as such.
    let mut names: Vec<String> = csv_fields(text, sep)
        .unwrap_or_default()
        .into_iter()
        .map(|(n, _)| n.to_ascii_lowercase())
        .collect();
    if names.len() > 1 && names.last().is_some_and(String::is_empty) {
        names.pop();
    }
    (sep, names)
}

fn csv_entries(label: &str, text: &str, repairs: &mut Repairs) -> Result<Vec<Entry>> {
    // Lines end in LF or CRLF, or in a bare CR throughout (a classic Mac spreadsheet's export,
    // which was read as one line: its header).
    let bare_cr = super::text::bare_cr_lines(text.as_bytes());
    let lines: Box<dyn Iterator<Item = &str>> = if bare_cr {
        Box::new(text.split('\r'))
    } else {
        Box::new(text.lines())
    };
    // Comments as numpy's `loadtxt` reads them: from a `#` to the end of the line. `savetxt`
    // writes its header (`header=`, of one line or several) and footer (`footer=`) as comment
    // lines; a camera's numbers hold no `#`.
    let mut rows = lines
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim_end_matches('\r')))
        .filter(|(_, l)| !l.trim().is_empty());
    let matrix = matrix_header();
    // The header: the first line that is not a comment, or a comment that names the columns
    // (`# frame,fov,...`, as `savetxt(..., header=...)` writes it) before it; other comments
    // before it are passed over.
    let mut passed_over = None;
    let (hline, header, (sep, names)) = loop {
        let Some((n, line)) = rows.next() else {
            bail!(
                "{label}: no header line naming the columns ('{}' or '{}'): the file holds only \
                 comments",
                "frame,fov,m00,m01,...,m33",
                LOOK_AT_HEADER.join(",")
            );
        };
        let text = line.trim_start();
        match text.strip_prefix('#') {
            Some(comment) => {
                let parsed = csv_header(comment);
                if parsed.1 == matrix || parsed.1 == LOOK_AT_HEADER {
                    break (n, line, parsed);
                }
                passed_over.get_or_insert((n, line));
            }
            None => break (n, line, csv_header(text)),
        }
    };
    let is_matrix = names == matrix;
    if !is_matrix && names != LOOK_AT_HEADER {
        // A comment before it that the author may have meant as the header.
        let comment = passed_over
            .map(|(n, c)| format!("; the comment at line {n}: '{}' names no columns", quote(c)))
            .unwrap_or_default();
        // Where it parts from the form its third column points to (`m00`: the matrix form).
        let form: Vec<&str> = if names.get(2).is_some_and(|n| n.starts_with('m')) {
            matrix.iter().map(String::as_str).collect()
        } else {
            LOOK_AT_HEADER.to_vec()
        };
        let parts = (0..names.len().max(form.len()))
            .find(|&i| names.get(i).map(String::as_str) != form.get(i).copied())
            .map(|i| match (names.get(i), form.get(i)) {
                (Some(got), Some(want)) => {
                    format!(
                        "; column {} is '{}' where '{want}' belongs",
                        i + 1,
                        quote(got)
                    )
                }
                (Some(got), None) => format!(
                    "; column {} ('{}') is one past the form's {}",
                    i + 1,
                    quote(got),
                    form.len()
                ),
                (None, Some(want)) => format!("; it ends before column {} ('{want}')", i + 1),
                (None, None) => String::new(),
            })
            .unwrap_or_default();
        bail!(
            "{label}: line {hline}: header '{}' is neither '{}' nor '{}' (in any case, \
             separated by commas or tabs, or by semicolons with decimal commas){parts}{comment}",
            quote(header),
            "frame,fov,m00,m01,...,m33",
            LOOK_AT_HEADER.join(",")
        );
    }
    // The rows after it, each up to its comment, if any; a line that is all comment is none.
    let rows: Vec<(usize, Vec<(String, bool)>)> = rows
        .map(|(n, row)| (n, row.split_once('#').map_or(row, |(data, _)| data)))
        .filter(|(_, row)| !row.trim().is_empty())
        .map(|(n, row)| match csv_fields(row, sep) {
            Ok(fields) => Ok((n, fields)),
            Err(e) => Err(anyhow!("{label}: line {n}: {e}")),
        })
        .collect::<Result<_>>()?;
    // Separated by semicolons or tabs, numbers have decimal commas, or else points; a file that
    // writes both may group thousands with one of them (`1.000` in a German locale is 1000),
    // and is refused rather than read a thousand times off.
    if sep != ',' {
        let with = |mark: char| {
            rows.iter()
                .find_map(|(n, fields)| Some((*n, fields.iter().find(|f| f.0.contains(mark))?)))
        };
        if let (Some((a, fa)), Some((b, fb))) = (with(','), with('.')) {
            bail!(
                "{label}: numbers with a decimal comma (line {a}: '{}') and with a point (line \
                 {b}: '{}'): one of them may group thousands; write every number with a point",
                quote(&fa.0),
                quote(&fb.0)
            );
        }
        // Points alone: a spreadsheet of such a locale writes 1000 as `1.000`, which reads as
        // 1 (a camera a thousand times nearer, without a word).
        for (n, fields) in &rows {
            for f in fields.iter().filter(|f| may_group_thousands(&f.0)) {
                repairs.note(label, *n, POINT_MAY_GROUP, || format!("'{}'", quote(&f.0)))?;
            }
        }
    }
    let mut entries = Vec::new();
    for (n, fields) in rows {
        let mut fields: Vec<String> = fields.into_iter().map(|f| decimal_point(f, sep)).collect();
        // A row of empty cells (a spreadsheet's last row): no frame.
        if fields.iter().all(String::is_empty) {
            continue;
        }
        // A separator after the last column, on the header or not (a spreadsheet ends every
        // data row with one and the header without, or the other way round).
        if fields.len() == names.len() + 1 && fields.last().is_some_and(String::is_empty) {
            fields.pop();
        }
        let fields: Vec<&str> = fields.iter().map(String::as_str).collect();
        let at = format!("line {n}");
        if fields.len() != names.len() {
            bail!(
                "{label}: {at}: {} fields, but the header (line {hline}) names {}",
                fields.len(),
                names.len()
            );
        }
        let frame = frame_number(fields[0]).ok_or_else(|| not_a_frame(label, &at, fields[0]))?;
        let fail = |why: String| anyhow!("{label}: {at}: frame {frame}: {why}");
        let fov = number("fov", fields[1]).map_err(fail)?;
        let form = if is_matrix {
            let mut m = [0.0f64; 16];
            for (i, v) in m.iter_mut().enumerate() {
                *v = number(&matrix[i + 2], fields[i + 2]).map_err(fail)?;
            }
            let eye = translation(|i| fields[i + 2], |i| matrix[i + 2].clone()).map_err(fail)?;
            Form::Matrix(m, eye)
        } else {
            let mut v = [[0.0f32; 3]; 3];
            for (i, x) in v.iter_mut().flatten().enumerate() {
                *x = number(LOOK_AT_HEADER[i + 2], fields[i + 2]).map_err(fail)?;
            }
            let mut exact = [[0.0f64; 3]; 2];
            for (i, x) in exact.iter_mut().flatten().enumerate() {
                *x = number(LOOK_AT_HEADER[i + 2], fields[i + 2]).map_err(fail)?;
            }
            Form::LookAt {
                position: v[0],
                look_at: v[1],
                up: v[2],
                exact,
            }
        };
        entries.push(Entry {
            at,
            line: n,
            frame,
            fov,
            form,
        });
    }
    Ok(entries)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    const ID: &str = "[1, 0, 0, 0.5, 0, 1, 0, 1.5, 0, 0, 1, 4, 0, 0, 0, 1]";

    fn json(entries: &[String]) -> String {
        format!("{{\"frames\": [\n{}\n]}}\n", entries.join(",\n"))
    }

    fn entry(frame: u32, matrix: &str) -> String {
        format!("  {{\"frame\": {frame}, \"fov\": 40.0, \"matrix\": {matrix}}}")
    }

    /// The error of a file that must be refused: one line.
    fn refused(name: &str, text: &str, frames: u32) -> String {
        let format = Format::of(name).unwrap();
        let e = parse(
            name,
            text.as_bytes(),
            format,
            frames,
            &mut Repairs::new(false),
        )
        .err()
        .unwrap_or_else(|| panic!("{name} loaded:\n{text}"));
        let e = format!("{e:#}");
        assert!(!e.contains('\n'), "more than one line: {e}");
        e
    }

    #[test]
    fn both_forms_load() {
        let text = json(&[
            entry(0, ID),
            "  {\"frame\": 1, \"fov\": 30, \"position\": [0.5, 1.5, 4], \"look_at\": [0.5, 1.5, 3], \
             \"up\": [0, 1, 0]}"
                .to_string(),
        ]);
        let poses = parse(
            "c.json",
            text.as_bytes(),
            Format::Json,
            2,
            &mut Repairs::new(false),
        )
        .unwrap();
        let eye = Vec3::new(0.5, 1.5, 4.0);
        assert_eq!(
            poses[0],
            Pose {
                eye,
                view: -Vec3::Z,
                up: Vec3::Y,
                fov: 40.0
            }
        );
        assert_eq!(poses[1].view, -Vec3::Z);
        assert_eq!(poses[1].fov, 30.0);
        // CRLF, and bare CR throughout (a classic Mac spreadsheet's export: it was read as one
        // line, its header, and refused).
        for csv in [
            "frame,fov,px,py,pz,lx,ly,lz,ux,uy,uz\r\n0, 40, 0.5,1.5,4, 0.5,1.5,3, 0,1,0\r\n\n",
            "frame,fov,px,py,pz,lx,ly,lz,ux,uy,uz\r0, 40, 0.5,1.5,4, 0.5,1.5,3, 0,1,0\r\r",
        ] {
            let p = parse(
                "c.csv",
                csv.as_bytes(),
                Format::Csv,
                1,
                &mut Repairs::new(false),
            )
            .unwrap_or_else(|e| panic!("{csv:?}: {e:#}"));
            assert_eq!((p[0].eye, p[0].view, p[0].up), (eye, -Vec3::Z, Vec3::Y));
        }
        let m: Vec<String> = ["frame", "fov"]
            .iter()
            .map(|s| s.to_string())
            .chain((0..16).map(|i| format!("m{}{}", i / 4, i % 4)))
            .collect();
        let row = ID.trim_matches(['[', ']']).replace(' ', "");
        let csv = format!("\u{feff}{}\n0,40,{row}\n", m.join(","));
        assert_eq!(
            parse(
                "c.csv",
                csv.as_bytes(),
                Format::Csv,
                1,
                &mut Repairs::new(false)
            )
            .unwrap(),
            poses[..1]
        );
        // A frame column that went through floating point, and numpy's `savetxt` header (a
        // comment) and numbers: the same cameras.
        let numpy = |x: &str| format!("{:.18e}", x.trim().parse::<f64>().unwrap());
        let csv = format!(
            "# {}\n{},{},{}\n",
            m.join(","),
            numpy("0"),
            numpy("40"),
            row.split(',').map(numpy).collect::<Vec<_>>().join(",")
        );
        let p = parse(
            "c.csv",
            csv.as_bytes(),
            Format::Csv,
            1,
            &mut Repairs::new(false),
        );
        assert_eq!(p.unwrap_or_else(|e| panic!("{csv}: {e:#}")), poses[..1]);
        // A negative zero is the frame 0 too (it was refused as not a whole number).
        for zero in ["0.0", "-0", "-0.0"] {
            let text = json(&[
                entry(0, ID).replace("\"frame\": 0", &format!("\"frame\": {zero}")),
                entry(1, ID).replace("\"frame\": 1", "\"frame\": 1e0"),
            ]);
            let p = parse(
                "c.json",
                text.as_bytes(),
                Format::Json,
                2,
                &mut Repairs::new(false),
            );
            assert_eq!(
                p.unwrap_or_else(|e| panic!("{zero}: {e:#}"))[..1],
                poses[..1]
            );
        }
    }

    #[test]
    fn coordinates_are_read_as_f32_from_their_text() {
        // The shortest text of an f32 reads back as that f32 (through f64 it could round twice).
        let x = 0.6893617f32;
        let text = json(&[format!(
            "{{\"frame\": 0, \"fov\": 40, \"position\": [{x}, 0, 0], \"look_at\": [0, 0, -1], \
             \"up\": [0, 1, 0]}}"
        )]);
        let p = parse(
            "c.json",
            text.as_bytes(),
            Format::Json,
            1,
            &mut Repairs::new(false),
        )
        .unwrap();
        assert_eq!(p[0].eye.x.to_bits(), x.to_bits());
    }

    #[test]
    fn frames_must_be_each_frame_once_in_order() {
        let f = |frames: &[u32]| json(&frames.iter().map(|&f| entry(f, ID)).collect::<Vec<_>>());
        for (frames, n, want) in [
            (&[0, 2][..], 3, "c.json: line 3 (entry 2): frame 2: frame 1 is missing"),
            (&[1, 2], 3, "c.json: line 2 (entry 1): frame 1: frame 0 is missing: a camera file numbers the scene's frames from 0 (renumber the file's frames 1, 2, ... as 0, 1, ...)"),
            (&[1, 0], 2, "c.json: line 2 (entry 1): frame 1: out of order: frame 0 comes after it, at line 3 (entry 2)"),
            (&[0, 2, 1], 3, "c.json: line 3 (entry 2): frame 2: out of order: frame 1 comes after it, at line 4 (entry 3)"),
            (&[0, 1, 1], 3, "c.json: line 4 (entry 3): frame 1: given twice (also at line 3 (entry 2))"),
            (&[0, 1, 2, 0], 4, "c.json: line 5 (entry 4): frame 0: given twice (also at line 2 (entry 1))"),
            (&[0, 1, 2], 2, "c.json: line 4 (entry 3): frame 2: past the last frame (1)"),
            (&[0, 5], 3, "c.json: line 3 (entry 2): frame 5: past the last frame (2)"),
            (&[0, 1], 3, "c.json: frame 2 is missing: the scene has 3 frames, the file gives 2 (the last entry, frame 1, is at line 3 (entry 2))"),
            (&[], 1, "c.json: frame 0 is missing: the scene has 1 frames, the file gives 0"),
        ] {
            let e = refused("c.json", &f(frames), n);
            assert!(e.starts_with(want), "{frames:?}:\n  want {want}\n  got  {e}");
        }
    }

    #[test]
    fn eyes_far_out_are_given_from_the_origin_in_f64() {
        // 5x10^6 units out f32 rounds to half a unit: the fraction survives only if the origin
        // is subtracted before the rounding, in both forms.
        let origin = DVec3::new(5.1e6, 0.0, -3.3e5);
        let matrix = "[1, 0, 0, 5100000.3, 0, 1, 0, 1.25, 0, 0, 1, -329999.3, 0, 0, 0, 1]";
        let look_at = "  {\"frame\": 0, \"fov\": 40.0, \"position\": [5100000.3, 1.25, \
                       -329999.3], \"look_at\": [5100000.3, 1.25, -330009.3], \"up\": [0, 1, 0]}";
        for text in [json(&[entry(0, matrix)]), json(&[look_at.to_string()])] {
            let p = parse_from(
                "c.json",
                text.as_bytes(),
                Format::Json,
                1,
                &mut Repairs::new(false),
                origin,
            )
            .unwrap();
            let want = glam::Vec3::new(0.3, 1.25, 0.7);
            assert!(
                (p[0].eye - want).abs().max_element() < 1e-6,
                "{text}: {}",
                p[0].eye
            );
            assert!(
                p[0].view.normalize().abs_diff_eq(-glam::Vec3::Z, 1e-6),
                "{text}"
            );
        }
    }

    #[test]
    fn a_matrix_given_as_four_rows_is_read_row_major() {
        // A camera at (1, 2, 3) turned 90 degrees about +Y, flat and as numpy's tolist() rows.
        let flat = "[0, 0, 1, 1, 0, 1, 0, 2, -1, 0, 0, 3, 0, 0, 0, 1]";
        let rows = "[[0, 0, 1, 1], [0, 1, 0, 2], [-1, 0, 0, 3], [0, 0, 0, 1]]";
        let read = |m: &str| {
            let text = json(&[entry(0, m)]);
            parse(
                "c.json",
                text.as_bytes(),
                Format::Json,
                1,
                &mut Repairs::new(false),
            )
            .unwrap()
        };
        assert_eq!(read(rows), read(flat));
        assert_eq!(read(rows)[0].eye, glam::Vec3::new(1.0, 2.0, 3.0));
        let m = |s: &str| json(&[entry(0, s)]);
        for (matrix, want) in [
            (
                "[[1, 0, 0, 0]]",
                "frame 0: matrix is given as 1 row of 4 numbers: give 16 numbers",
            ),
            (
                "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]",
                "frame 0: matrix is given as 3 rows of 3, 3, 3 numbers: give 16 numbers, \
                 row-major, or 4 rows of 4",
            ),
            (
                "[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], 1]",
                "frame 0: matrix is given as 4 rows of 4, 4, 4, 1 numbers",
            ),
        ] {
            let e = refused("c.json", &m(matrix), 1);
            assert!(e.contains(want), "{matrix}:\n  want {want}\n  got  {e}");
        }
    }

    #[test]
    fn bad_matrices_are_refused() {
        let m = |s: &str| json(&[entry(0, s)]);
        for (matrix, want) in [
            (
                "[0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1]",
                "frame 0: matrix is singular or nearly so",
            ),
            // Y and Z the same axis.
            (
                "[1, 0, 0, 0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 0, 0, 1]",
                "matrix is singular",
            ),
            // Y and Z 1e-5 radians apart: nearly parallel.
            (
                "[1, 0, 0, 0, 0, 1, 1, 0, 0, 1, 1.00001, 0, 0, 0, 0, 1]",
                "matrix is singular or nearly so",
            ),
            (
                "[-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]",
                "matrix is mirrored",
            ),
            (
                "[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 1, 1]",
                "matrix bottom row [0.0, 0.0, 1.0, 1.0] is not [0, 0, 0, 1]",
            ),
            // Column by column: the translation in the bottom row.
            (
                "[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.5, 1, 3, 1]",
                "its last column is [0, 0, 0, 1]: it looks written column by column",
            ),
            (
                "[1, 0, 0, 1e19, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]",
                "matrix element m03 = 1e19 is too large",
            ),
            (
                "[1, 0, 0, 1.0000001e18, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]",
                "matrix element m03 = 1.0000001e18 is too large (at most 1e18)",
            ),
            (
                "[1, 0, 0, 1e400, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]",
                "matrix element m03 = inf is not finite",
            ),
            (
                "[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0]",
                "matrix has 15 numbers, not 16",
            ),
            (
                "[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, \"1\"]",
                "matrix '\"1\"' is not a number",
            ),
        ] {
            let e = refused("c.json", &m(matrix), 1);
            assert!(e.starts_with("c.json: line 2 (entry 1): frame 0: "), "{e}");
            assert!(e.contains(want), "{matrix}:\n  want {want}\n  got  {e}");
        }
        // A scaled matrix is fine: only its rotation is used, also where the scale is so
        // small that the determinant underflows (1e-330 from 1e-110: it was "singular").
        for scaled in [
            "[3, 0, 0, 0, 0, 3, 0, 0, 0, 0, 3, 0, 0, 0, 0, 1]",
            "[1e-110, 0, 0, 0, 0, 1e-110, 0, 0, 0, 0, 1e-110, 0, 0, 0, 0, 1]",
            "[1e-200, 0, 0, 0, 0, 1e-250, 0, 0, 0, 0, 1e-300, 0, 0, 0, 0, 1]",
        ] {
            let p = parse(
                "c.json",
                m(scaled).as_bytes(),
                Format::Json,
                1,
                &mut Repairs::new(false),
            )
            .unwrap_or_else(|e| panic!("{scaled}: {e:#}"));
            assert_eq!((p[0].view, p[0].up), (-Vec3::Z, Vec3::Y), "{scaled}");
        }
    }

    #[test]
    fn a_sheared_matrix_is_made_rigid_with_a_warning() {
        // Z tilted 42 degrees towards Y (a camera under a non-uniformly scaled, rotated parent):
        // the view is kept, up made perpendicular, and the loader says so once for the file,
        // or refuses under strict loading. A shear of 0.01 degrees (an exporter's rounding) is
        // silent.
        let (s, c) = 42f64.to_radians().sin_cos();
        let sheared = format!("[1, 0, 0, 0, 0, 1, {s}, 0, 0, 0, {c}, 0, 0, 0, 0, 1]");
        let text = json(&[entry(0, &sheared), entry(1, &sheared)]);
        let mut r = Repairs::new(false);
        let p = parse("c.json", text.as_bytes(), Format::Json, 2, &mut r).unwrap();
        let view = -Vec3::new(0.0, s as f32, c as f32);
        assert!(p[0].view.abs_diff_eq(view, 1e-6), "{}", p[0].view);
        let cam = crate::camera::Camera::from_pose(&p[0], 4, 4);
        assert!(
            cam.up.dot(cam.forward).abs() < 1e-6 && cam.up.y > 0.7,
            "{}",
            cam.up
        );
        assert_eq!(
            r.into_warnings(),
            [
                "c.json: 2 sheared cameras made rigid (view kept, up made perpendicular to it) \
              (first at line 2: frame 0: the matrix's axes are 42.00 degrees from perpendicular)"
            ]
        );
        let e = parse(
            "c.json",
            text.as_bytes(),
            Format::Json,
            2,
            &mut Repairs::new(true),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("42.00 degrees from perpendicular") && e.contains("strict"),
            "{e}"
        );
        let slight = 0.01f64.to_radians().sin();
        let text = json(&[entry(
            0,
            &format!("[1, 0, 0, 0, 0, 1, {slight}, 0, 0, 0, 1, 0, 0, 0, 0, 1]"),
        )]);
        let mut r = Repairs::new(true);
        parse("c.json", text.as_bytes(), Format::Json, 1, &mut r).unwrap();
        assert!(r.into_warnings().is_empty());
    }

    #[test]
    fn malformed_json_is_refused_naming_the_line() {
        for (text, want) in [
            (
                "{\"frames\": [\n{\"frame\": 0, \"fov\": NaN, \"matrix\": []}]}".to_string(),
                "c.json: line 2: expected value (NaN or Infinity: a camera's numbers must be finite",
            ),
            (
                format!("[{}]", entry(0, ID)),
                "c.json: line 1: the file is an array: a camera file is an object, {\"frames\": [...]}",
            ),
            (
                format!("// exported from the shot\n{}", json(&[entry(0, ID)])),
                "c.json: line 1: expected value (a comment: JSON has none; remove it)",
            ),
            (
                json(&[entry(0, ID)]).replacen('\n', "\n/* camera */ ", 1),
                "c.json: line 2: expected value (a comment: JSON has none; remove it)",
            ),
            (json(&[entry(0, ID).replace("fov", "fvo")]), "c.json: line 2 (entry 1): unknown key 'fvo'"),
            // A file on one line (Python's `json.dump`) says the column too.
            (
                format!("{{\"frames\": [{}, {}, , {}]}}", entry(0, ID), entry(1, ID), entry(2, ID)),
                "c.json: line 1, column ",
            ),
            // Lines ended by a bare CR are lines (serde counted LFs alone: line 1).
            (json(&[entry(0, ID), entry(1, ID).replace("fov", "fvo")]).replace('\n', "\r"), "c.json: line 3 (entry 2): unknown key 'fvo'"),
            (json(&[entry(0, ID), entry(1, ID).replace("fov", "fvo")]).replace('\n', "\r\n"), "c.json: line 3 (entry 2): unknown key 'fvo'"),
            (json(&[entry(0, ID).replace("\"frame\": 0", "\"frame\": 0.5")]), "c.json: line 2 (entry 1): frame '0.5' is not a frame number (a whole number from 0 to 4294967295)"),
            (json(&[entry(0, ID).replace("\"frame\": 0", "\"frame\": 1e-400")]), "c.json: line 2 (entry 1): frame '1e-400' is not a frame number"),
            (json(&[entry(0, ID).replace("\"frame\": 0", "\"frame\": 0.99999999999999999")]), "c.json: line 2 (entry 1): frame '0.99999999999999999' is not a frame number"),
            (json(&[entry(0, ID).replace("\"frame\": 0", "\"frame\": 4294967296.0")]), "c.json: line 2 (entry 1): frame '4294967296.0' is not a frame number (a whole number from 0 to 4294967295)"),
            (json(&[entry(0, ID).replace("\"frame\": 0", "\"frame\": \"0\"")]), "c.json: line 2 (entry 1): frame '\"0\"' is not a frame number"),
            (json(&[entry(0, ID).replace("\"frame\": 0", "\"frame\": -1.0")]), "c.json: line 2 (entry 1): frame '-1.0' is not a frame number"),
            (json(&[entry(0, ID).replace("40.0", "180")]), "c.json: line 2 (entry 1): frame 0: fov 180 must be in (0, 180) degrees"),
            (json(&[entry(0, ID).replace("40.0", "179.9999999")]), "frame 0: fov 179.9999999 rounds to 180 degrees in single precision: at most 179.99998"),
            (
                json(&[entry(0, ID).replace('}', ", \"position\": [0, 0, 0]}")]),
                "frame 0: both matrix and position/look_at/up: give one",
            ),
            (
                json(&["{\"frame\": 0, \"fov\": 40, \"position\": [0, 0, 0], \"up\": [0, 1, 0]}".into()]),
                "frame 0: needs matrix, or position, look_at and up",
            ),
            (
                json(&["{\"frame\": 0, \"fov\": 40, \"position\": [0, 0, 0], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0]}".into()]),
                "frame 0: look_at coincides with position",
            ),
            ("".into(), "c.json: the file is empty"),
        ] {
            let e = refused("c.json", &text, 1);
            assert!(e.contains(want), "\n  want {want}\n  got  {e}");
        }
    }

    #[test]
    fn csv_as_spreadsheets_write_it_is_read() {
        let load = |text: &str| {
            parse(
                "c.csv",
                text.as_bytes(),
                Format::Csv,
                2,
                &mut Repairs::new(false),
            )
            .unwrap_or_else(|e| panic!("{e:#}\n{text}"))
        };
        let h = LOOK_AT_HEADER.join(",");
        let plain = load(&format!(
            "{h}\n0,40,0.5,0,3,0,0,0,0,1,0\n1,40.5,0.25,0,3,0,0,0,0,1,0\n"
        ));
        let quoted_header = LOOK_AT_HEADER.map(|n| format!("\"{n}\"")).join(",");
        for text in [
            // R's write.csv and pandas' QUOTE_NONNUMERIC: quoted names.
            format!("{quoted_header}\n0,40,0.5,0,3,0,0,0,0,1,0\n1,40.5,0.25,0,3,0,0,0,0,1,0\n"),
            // Excel and LibreOffice in a German or French locale: semicolons, decimal commas.
            format!(
                "{}\r\n0;40;0,5;0;3;0;0;0;0;1;0\r\n1;40,5;0,25;0;3;0;0;0;0;1;0\r\n",
                LOOK_AT_HEADER.join(";")
            ),
            // Commas between fields, decimal commas in quotes.
            format!("{h}\n0,40,\"0,5\",0,3,0,0,0,0,1,0\n1,\"40,5\",\"0,25\",0,3,0,0,0,0,1,0\n"),
            // A last row of empty cells, capitals, a separator after the last column.
            format!("{h}\n0,40,0.5,0,3,0,0,0,0,1,0\n1,40.5,0.25,0,3,0,0,0,0,1,0\n,,,,,,,,,,\n"),
            format!(
                "{}\n0,40,0.5,0,3,0,0,0,0,1,0\n1,40.5,0.25,0,3,0,0,0,0,1,0\n",
                h.to_uppercase()
            ),
            format!("{h},\n0,40,0.5,0,3,0,0,0,0,1,0,\n1,40.5,0.25,0,3,0,0,0,0,1,0,\n"),
            // The separator after the last column on the data rows alone, or the header alone.
            format!("{h}\n0,40,0.5,0,3,0,0,0,0,1,0,\n1,40.5,0.25,0,3,0,0,0,0,1,0,\n"),
            format!("{h},\n0,40,0.5,0,3,0,0,0,0,1,0\n1,40.5,0.25,0,3,0,0,0,0,1,0\n"),
            // Comments as numpy's savetxt writes them and loadtxt reads them: a header of
            // several comment lines (`header="a\\nb"`), a footer (`footer=`), a comment after a
            // row's numbers, a comment line between rows; and a comment before a plain header.
            format!(
                "# exported from shot_v2.blend\n# {h}\n0,40,0.5,0,3,0,0,0,0,1,0\n\
                 1,40.5,0.25,0,3,0,0,0,0,1,0\n# end\n"
            ),
            format!(
                "# {h}\n# units: metres\n0,40,0.5,0,3,0,0,0,0,1,0 # key\n#\n\
                 1,40.5,0.25,0,3,0,0,0,0,1,0#\n"
            ),
            format!("# made by hand\n{h}\n0,40,0.5,0,3,0,0,0,0,1,0\n1,40.5,0.25,0,3,0,0,0,0,1,0\n"),
        ] {
            assert_eq!(load(&text), plain, "{text}");
        }
        // A file of comments alone, and a comment that names other columns before the rows.
        let e = refused("c.csv", &format!("# exported\n#{h}x\n"), 1);
        assert!(e.contains("no header line naming the columns"), "{e}");
        let e = refused("c.csv", "# frame,fov,x,y,z\n0,40,0.5,0,3,0,0,0,0,1,0\n", 1);
        assert!(
            e.contains("line 2: header '0,40,0.5,0,3,0,0,0,0,1,0' is neither")
                && e.contains("line 1: '# frame,fov,x,y,z' names no columns"),
            "{e}"
        );
        // "1,000" may group thousands: not read as 1.
        let e = refused(
            "c.csv",
            &format!("{h}\n0,40,\"1,000\",0,3,0,0,0,0,1,0\n1,40,0,0,3,0,0,0,0,1,0\n"),
            2,
        );
        assert!(e.contains("px '1,000' is not a number"), "{e}");
        // Decimal commas and points in one file separated by semicolons: `1.000` may be 1000.
        let e = refused(
            "c.csv",
            &format!(
                "{}\n0;40;0,5;0;3;0;0;0;0;1;0\n1;40;1.000;0;3;0;0;0;0;1;0\n",
                LOOK_AT_HEADER.join(";")
            ),
            2,
        );
        assert!(
            e.contains("decimal comma (line 2: '0,5') and with a point (line 3: '1.000')"),
            "{e}"
        );
        // Points alone in a file separated by semicolons: `1.000` is read as 1, with a
        // warning (it was read so without one); `0.125` and `1.25` cannot group thousands.
        let text = format!(
            "{}\n0;40;0.125;0;3;0;0;0;0;1;0\n1;40;1.000;1.25;3;0;0;0;0;1;0\n",
            LOOK_AT_HEADER.join(";")
        );
        let mut r = Repairs::new(false);
        let poses = parse("c.csv", text.as_bytes(), Format::Csv, 2, &mut r).unwrap();
        assert_eq!(poses[1].eye, Vec3::new(1.0, 1.25, 3.0));
        let w = r.into_warnings();
        assert!(
            w.len() == 1
                && w[0].starts_with("c.csv: line 3: '1.000': a number with three digits after"),
            "{w:?}"
        );
    }

    #[test]
    fn malformed_csv_is_refused_naming_the_line() {
        let h = LOOK_AT_HEADER.join(",");
        let ok = "0,40,0,0,3,0,0,0,0,1,0";
        for (text, want) in [
            (
                format!("frame,fov,x,y,z\n{ok}\n"),
                "c.csv: line 1: header 'frame,fov,x,y,z' is neither",
            ),
            // Where the header parts from its form is said.
            (
                format!("frame,fov,x,y,z\n{ok}\n"),
                "; column 3 is 'x' where 'px' belongs",
            ),
            (
                format!("{h},focal\n{ok}\n"),
                "; column 12 ('focal') is one past the form's 11",
            ),
            (
                format!("frame\tfov\tpx\n{ok}\n"),
                "separated by commas or tabs",
            ),
            (
                format!("frame\tfov\tpx\n{ok}\n"),
                "; it ends before column 4 ('py')",
            ),
            (
                format!("{h}\n0,40,0,0,3,0,0,0,0,1\n"),
                "c.csv: line 2: 10 fields, but the header (line 1) names 11",
            ),
            (format!("{h}\n{ok},5\n"), "c.csv: line 2: 12 fields"),
            (
                format!("{h}\n0,40,nan,0,3,0,0,0,0,1,0\n"),
                "c.csv: line 2: frame 0: position [NaN, 0.0, 3.0] is not finite",
            ),
            (
                format!("{h}\n0,40,0,0,3e19,0,0,0,0,1,0\n"),
                "c.csv: line 2: frame 0: position [0.0, 0.0, 3e19] is too large",
            ),
            (
                format!("{h}\n0,40,0,0,3,0,0,0,0,0,1\n"),
                "c.csv: line 2: frame 0: up [0, 0, 1] is parallel to the view direction",
            ),
            (
                format!("{h}\n0,40,0,0,3,0,zero,0,0,1,0\n"),
                "c.csv: line 2: frame 0: ly 'zero' is not a number",
            ),
            (
                format!("{h}\n0.5,40,0,0,3,0,0,0,0,1,0\n"),
                "c.csv: line 2: frame '0.5' is not a frame number",
            ),
            (
                format!("{h}\n{ok}\n\n0,40,0,0,3,0,0,0,0,1,0\n"),
                "c.csv: line 4: frame 0: given twice (also at line 2)",
            ),
            (
                format!("{h}\n"),
                "c.csv: frame 0 is missing: the scene has 1 frames, the file gives 0",
            ),
        ] {
            let e = refused("c.csv", &text, 1);
            assert!(e.contains(want), "\n  want {want}\n  got  {e}");
        }
    }
}
