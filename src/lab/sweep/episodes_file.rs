//! A sweep's episodes as Parquet (`episodes.parquet`): one row per episode, in index order,
//! the sweep's [`Manifest`] as JSON in the file's key-value metadata (`flowgate.manifest`), so
//! a file alone says which sweep and shard it holds. pyarrow, DuckDB or pandas read it as is.
//!
//! | column | type | |
//! |---|---|---|
//! | `index` | uint64 | the episode's index in the sweep |
//! | `seed` | uint64 | the sweep's seed (index and seed replay the episode) |
//! | `outcome` | string | goal, collision, timeout, stall, fault, stopped |
//! | `min_clearance` | double, null | smallest clearance to an obstacle, m |
//! | `min_wall_clearance` | double, null | smallest clearance to a wall or static obstacle, m |
//! | `duration` | double | when the episode ended, s |
//! | `path_length` | double | the robot's path, m |
//! | `speed_ratio` | double | fastest obstacle over the robot's speed limit |
//! | `delay` | double | the episode's sensing delay, s |
//! | `active_contact` | boolean | a collision the robot drove into |
//! | `discomfort` | double | the share of the episode a person was uncomfortably near |

use std::fs::File;
use std::path::Path;
use std::sync::Arc;

use parquet::basic::Compression;
use parquet::column::reader::ColumnReader;
use parquet::column::writer::ColumnWriter;
use parquet::data_type::ByteArray;
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use parquet::file::reader::{FileReader, SerializedFileReader};
use parquet::file::writer::SerializedFileWriter;

use super::{Episode, Manifest};
use crate::lab::Outcome;

/// The key of the manifest in the file's key-value metadata.
pub const MANIFEST_KEY: &str = "flowgate.manifest";

/// The file's schema, in Parquet's message syntax.
pub const SCHEMA: &str = "message flowgate_sweep_episode {
    REQUIRED INT64 index (INTEGER(64,false));
    REQUIRED INT64 seed (INTEGER(64,false));
    REQUIRED BYTE_ARRAY outcome (STRING);
    OPTIONAL DOUBLE min_clearance;
    OPTIONAL DOUBLE min_wall_clearance;
    REQUIRED DOUBLE duration;
    REQUIRED DOUBLE path_length;
    REQUIRED DOUBLE speed_ratio;
    REQUIRED DOUBLE delay;
    REQUIRED BOOLEAN active_contact;
    REQUIRED DOUBLE discomfort;
}";

/// Rows per row group: a reader holds one group at a time.
const ROW_GROUP: usize = 1 << 20;

/// Why an episodes file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum EpisodesFileError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: {source}")]
    Parquet { path: String, source: parquet::errors::ParquetError },
    #[error("{path}: not a flowgate episodes file: {why}")]
    Foreign { path: String, why: String },
    #[error("{path}: row {row}: {why}")]
    BadRow { path: String, row: u64, why: String },
}

/// Write `episodes` (in index order) and their `manifest` to `path`.
pub fn write(path: &Path, manifest: &Manifest, episodes: &[Episode]) -> Result<(), EpisodesFileError> {
    let at = || path.display().to_string();
    let pq = |source| EpisodesFileError::Parquet { path: at(), source };
    let schema = Arc::new(parquet::schema::parser::parse_message_type(SCHEMA).map_err(pq)?);
    let json = serde_json::to_string(manifest).expect("a manifest serialises");
    let props = WriterProperties::builder()
        .set_compression(Compression::ZSTD(Default::default()))
        .set_key_value_metadata(Some(vec![KeyValue::new(MANIFEST_KEY.to_owned(), json)]))
        .set_created_by(format!("flowgate {}", env!("CARGO_PKG_VERSION")))
        .build();
    let file = File::create(path).map_err(|source| EpisodesFileError::Io { path: at(), source })?;
    let mut writer = SerializedFileWriter::new(file, schema, Arc::new(props)).map_err(pq)?;
    for group in episodes.chunks(ROW_GROUP) {
        let mut rows = writer.next_row_group().map_err(pq)?;
        let mut column = 0;
        while let Some(mut col) = rows.next_column().map_err(pq)? {
            write_column(col.untyped(), column, manifest.seed, group).map_err(pq)?;
            col.close().map_err(pq)?;
            column += 1;
        }
        rows.close().map_err(pq)?;
    }
    writer.close().map_err(pq)?;
    Ok(())
}

/// Column `column` of [`SCHEMA`] for `group`.
fn write_column(
    writer: &mut ColumnWriter<'_>,
    column: usize,
    seed: u64,
    group: &[Episode],
) -> parquet::errors::Result<()> {
    // Parquet stores unsigned 64-bit integers in INT64, bit for bit.
    let u64s = |f: fn(&Episode) -> u64| group.iter().map(|e| f(e) as i64).collect::<Vec<_>>();
    let f64s = |f: fn(&Episode) -> f64| group.iter().map(f).collect::<Vec<_>>();
    let optional = |f: fn(&Episode) -> Option<f64>| {
        let defs: Vec<i16> = group.iter().map(|e| i16::from(f(e).is_some())).collect();
        (group.iter().filter_map(f).collect::<Vec<_>>(), defs)
    };
    match (column, writer) {
        (0, ColumnWriter::Int64ColumnWriter(w)) => w.write_batch(&u64s(|e| e.index), None, None),
        (1, ColumnWriter::Int64ColumnWriter(w)) => w.write_batch(&vec![seed as i64; group.len()], None, None),
        (2, ColumnWriter::ByteArrayColumnWriter(w)) => {
            let names: Vec<ByteArray> = group.iter().map(|e| ByteArray::from(e.outcome.to_string().as_str())).collect();
            w.write_batch(&names, None, None)
        }
        (3, ColumnWriter::DoubleColumnWriter(w)) => {
            let (values, defs) = optional(|e| e.min_clearance);
            w.write_batch(&values, Some(&defs), None)
        }
        (4, ColumnWriter::DoubleColumnWriter(w)) => {
            let (values, defs) = optional(|e| e.min_wall_clearance);
            w.write_batch(&values, Some(&defs), None)
        }
        (5, ColumnWriter::DoubleColumnWriter(w)) => w.write_batch(&f64s(|e| e.duration), None, None),
        (6, ColumnWriter::DoubleColumnWriter(w)) => w.write_batch(&f64s(|e| e.path_length), None, None),
        (7, ColumnWriter::DoubleColumnWriter(w)) => w.write_batch(&f64s(|e| e.speed_ratio), None, None),
        (8, ColumnWriter::DoubleColumnWriter(w)) => w.write_batch(&f64s(|e| e.delay), None, None),
        (9, ColumnWriter::BoolColumnWriter(w)) => {
            w.write_batch(&group.iter().map(|e| e.active_contact).collect::<Vec<_>>(), None, None)
        }
        (10, ColumnWriter::DoubleColumnWriter(w)) => w.write_batch(&f64s(|e| e.discomfort), None, None),
        (n, _) => unreachable!("column {n} of the schema has no writer"),
    }?;
    Ok(())
}

const OUTCOMES: [Outcome; 6] =
    [Outcome::Goal, Outcome::Collision, Outcome::Timeout, Outcome::Stall, Outcome::Fault, Outcome::Stopped];

/// The columns of one file, as read.
#[derive(Default)]
struct Columns {
    index: Vec<i64>,
    seed: Vec<i64>,
    outcome: Vec<ByteArray>,
    min_clearance: (Vec<f64>, Vec<i16>),
    min_wall_clearance: (Vec<f64>, Vec<i16>),
    doubles: [Vec<f64>; 4],
    active_contact: Vec<bool>,
    discomfort: Vec<f64>,
}

/// Read an episodes file: its manifest and its episodes, checked against [`SCHEMA`].
pub fn read(path: &Path) -> Result<(Manifest, Vec<Episode>), EpisodesFileError> {
    let at = || path.display().to_string();
    let pq = |source| EpisodesFileError::Parquet { path: at(), source };
    let foreign = |why: String| EpisodesFileError::Foreign { path: at(), why };
    let file = File::open(path).map_err(|source| EpisodesFileError::Io { path: at(), source })?;
    let reader = SerializedFileReader::new(file).map_err(pq)?;
    let meta = reader.metadata().file_metadata();
    let ours = parquet::schema::parser::parse_message_type(SCHEMA).map_err(pq)?;
    let theirs = meta.schema();
    if theirs.get_fields() != ours.get_fields() {
        let names = |t: &parquet::schema::types::Type| {
            t.get_fields().iter().map(|f| f.name().to_owned()).collect::<Vec<_>>().join(", ")
        };
        return Err(foreign(format!("its columns are [{}], expected [{}]", names(theirs), names(&ours))));
    }
    let json = meta
        .key_value_metadata()
        .and_then(|kv| kv.iter().find(|k| k.key == MANIFEST_KEY))
        .and_then(|k| k.value.clone())
        .ok_or_else(|| foreign(format!("no `{MANIFEST_KEY}` in its metadata")))?;
    let manifest: Manifest = serde_json::from_str(&json).map_err(|e| foreign(format!("its `{MANIFEST_KEY}`: {e}")))?;
    let mut columns = Columns::default();
    for g in 0..reader.num_row_groups() {
        let group = reader.get_row_group(g).map_err(pq)?;
        let rows = usize::try_from(group.metadata().num_rows()).unwrap_or(0);
        for c in 0..group.num_columns() {
            read_column(group.get_column_reader(c).map_err(pq)?, c, rows, &mut columns).map_err(pq)?;
        }
    }
    let episodes = episodes(columns, path)?;
    Ok((manifest, episodes))
}

/// Column `c` of a row group of `rows` rows, appended to `into`.
fn read_column(reader: ColumnReader, c: usize, rows: usize, into: &mut Columns) -> parquet::errors::Result<()> {
    use ColumnReader::{BoolColumnReader, ByteArrayColumnReader, DoubleColumnReader, Int64ColumnReader};
    match (c, reader) {
        (0, Int64ColumnReader(mut r)) => drain(&mut r, rows, None, &mut into.index),
        (1, Int64ColumnReader(mut r)) => drain(&mut r, rows, None, &mut into.seed),
        (2, ByteArrayColumnReader(mut r)) => drain(&mut r, rows, None, &mut into.outcome),
        (3, DoubleColumnReader(mut r)) => {
            let (values, defs) = &mut into.min_clearance;
            drain(&mut r, rows, Some(defs), values)
        }
        (4, DoubleColumnReader(mut r)) => {
            let (values, defs) = &mut into.min_wall_clearance;
            drain(&mut r, rows, Some(defs), values)
        }
        (5..=8, DoubleColumnReader(mut r)) => drain(&mut r, rows, None, &mut into.doubles[c - 5]),
        (9, BoolColumnReader(mut r)) => drain(&mut r, rows, None, &mut into.active_contact),
        (10, DoubleColumnReader(mut r)) => drain(&mut r, rows, None, &mut into.discomfort),
        // The schema was checked against ours: no other column reaches here.
        (n, _) => Err(parquet::errors::ParquetError::General(format!("column {n} is not of the schema"))),
    }
}

/// Every record of a column chunk of `rows` rows.
fn drain<T: parquet::data_type::DataType>(
    r: &mut parquet::column::reader::ColumnReaderImpl<T>,
    rows: usize,
    mut defs: Option<&mut Vec<i16>>,
    values: &mut Vec<T::T>,
) -> parquet::errors::Result<()> {
    let mut done = 0;
    while done < rows {
        let (records, _, _) = r.read_records(rows - done, defs.as_deref_mut(), None, values)?;
        if records == 0 {
            return Err(parquet::errors::ParquetError::General(format!("a column ends after {done} of {rows} rows")));
        }
        done += records;
    }
    Ok(())
}

/// The episodes the columns hold.
fn episodes(c: Columns, path: &Path) -> Result<Vec<Episode>, EpisodesFileError> {
    let bad =
        |row: usize, why: String| EpisodesFileError::BadRow { path: path.display().to_string(), row: row as u64, why };
    let nullable = |(values, defs): (Vec<f64>, Vec<i16>)| {
        let mut values = values.into_iter();
        defs.into_iter().map(move |d| if d > 0 { values.next() } else { None }).collect::<Vec<_>>()
    };
    let (min_clearance, min_wall_clearance) = (nullable(c.min_clearance), nullable(c.min_wall_clearance));
    let [duration, path_length, speed_ratio, delay] = c.doubles;
    let n = c.index.len();
    let lengths = [
        c.seed.len(),
        c.outcome.len(),
        min_clearance.len(),
        min_wall_clearance.len(),
        duration.len(),
        path_length.len(),
        speed_ratio.len(),
        delay.len(),
        c.active_contact.len(),
        c.discomfort.len(),
    ];
    if let Some(short) = lengths.iter().position(|&l| l != n) {
        return Err(bad(
            lengths[short].min(n),
            format!("column {} has {} rows, `index` {n}", short + 1, lengths[short]),
        ));
    }
    (0..n)
        .map(|i| {
            let name = c.outcome[i].as_utf8().map_err(|e| bad(i, format!("outcome: {e}")))?;
            let outcome = OUTCOMES.into_iter().find(|o| o.to_string() == name).ok_or_else(|| {
                bad(i, format!("outcome {name:?} is none of goal, collision, timeout, stall, fault, stopped"))
            })?;
            Ok(Episode {
                index: c.index[i] as u64,
                outcome,
                min_clearance: min_clearance[i],
                speed_ratio: speed_ratio[i],
                delay: delay[i],
                active_contact: c.active_contact[i],
                min_wall_clearance: min_wall_clearance[i],
                duration: duration[i],
                path_length: path_length[i],
                discomfort: c.discomfort[i],
            })
        })
        .collect()
}
