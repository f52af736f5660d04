//! The jobs and their state in a SQLite file (WAL): what was asked, when it moved
//! from queued to running to its end, where it wrote, its summary or error. A service
//! killed mid-job finds the job `running` when it starts again and marks it
//! `interrupted` (the service then recovers the frames it had written as they were
//! labelled as a partial dataset: `fpm_acquire::journal`).

use std::path::Path;
use std::sync::Mutex;
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result};
use rusqlite::{params, Connection, OptionalExtension};
use serde::Serialize;
use utoipa::ToSchema;

/// Where a job is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Waiting for the rig.
    Queued,
    /// On the rig now.
    Running,
    /// Finished as asked.
    Done,
    /// Finished with an error (`error` says which).
    Failed,
    /// Stopped by a client; what was captured is written.
    Cancelled,
    /// The service stopped while it ran (killed, the machine restarted).
    Interrupted,
}

impl JobState {
    fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
            JobState::Interrupted => "interrupted",
        }
    }

    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "queued" => JobState::Queued,
            "running" => JobState::Running,
            "done" => JobState::Done,
            "failed" => JobState::Failed,
            "cancelled" => JobState::Cancelled,
            "interrupted" => JobState::Interrupted,
            _ => return None,
        })
    }

    /// Whether the job has ended.
    pub fn is_final(self) -> bool {
        !matches!(self, JobState::Queued | JobState::Running)
    }
}

/// One job as stored.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct Job {
    /// Its id.
    pub id: i64,
    /// What kind of job ("acquire").
    pub kind: String,
    /// Where it is.
    pub state: JobState,
    /// The request as given.
    #[schema(value_type = Object)]
    pub request: serde_json::Value,
    /// Where it writes.
    pub out: String,
    /// When it was queued, started and ended, Unix seconds.
    pub created_s: f64,
    pub started_s: Option<f64>,
    pub finished_s: Option<f64>,
    /// Why it failed, was cancelled or interrupted.
    pub error: Option<String>,
    /// What it did (an acquisition's `acquisition.json`).
    #[schema(value_type = Option<Object>)]
    pub summary: Option<serde_json::Value>,
    /// Its report pages present now, relative to `out` (fetch them from
    /// `/api/jobs/{id}/files/…`).
    pub reports: Vec<String>,
}

impl Job {
    /// The report pages a job writes, in the order a person reads them (an
    /// acquisition's, a reconstruction's own).
    pub const REPORTS: [&'static str; 4] = [
        "acquisition.html",
        "reconstruction/report.html",
        "calibration.html",
        "report.html",
    ];

    /// With `reports` listing the pages that exist in `out`.
    pub fn with_reports(mut self) -> Self {
        let out = std::path::Path::new(&self.out);
        self.reports = Self::REPORTS
            .iter()
            .filter(|r| out.join(r).is_file())
            .map(|r| r.to_string())
            .collect();
        self
    }
}

/// The job database.
pub struct Store {
    conn: Mutex<Connection>,
    interrupted: Vec<i64>,
}

fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The database file created empty (SQLite takes an empty file as a new database)
/// or kept readable by its owner alone (0600): the job history holds every request
/// and its paths. SQLite gives its -wal and -shm files the database's permissions.
fn owner_only(path: &Path) -> Result<()> {
    use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
    let file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .mode(0o600)
        .open(path)
        .with_context(|| format!("opening {}", path.display()))?;
    let mode = file.metadata()?.permissions().mode() & 0o777;
    if mode & 0o077 != 0 {
        file.set_permissions(std::fs::Permissions::from_mode(0o600))
            .with_context(|| format!("making {} private (chmod 600)", path.display()))?;
    }
    // An older service's write-ahead log keeps the mode it was made with.
    for suffix in ["-wal", "-shm"] {
        let mut side = path.as_os_str().to_owned();
        side.push(suffix);
        let side = Path::new(&side);
        if side.exists() {
            std::fs::set_permissions(side, std::fs::Permissions::from_mode(0o600))
                .with_context(|| format!("making {} private (chmod 600)", side.display()))?;
        }
    }
    Ok(())
}

impl Store {
    /// Open (or create) the database at `path`; jobs a previous service left running
    /// are marked interrupted.
    pub fn open(path: &Path) -> Result<Self> {
        owner_only(path)?;
        let conn = Connection::open(path).with_context(|| format!("opening {}", path.display()))?;
        conn.pragma_update(None, "journal_mode", "WAL")
            .with_context(|| format!("{}: write-ahead log", path.display()))?;
        conn.execute_batch(
            "CREATE TABLE IF NOT EXISTS jobs (
                id INTEGER PRIMARY KEY AUTOINCREMENT,
                kind TEXT NOT NULL,
                state TEXT NOT NULL,
                request TEXT NOT NULL,
                out TEXT NOT NULL,
                created_s REAL NOT NULL,
                started_s REAL,
                finished_s REAL,
                error TEXT,
                summary TEXT
            );",
        )
        .with_context(|| format!("{}: the jobs table", path.display()))?;
        let interrupted: Vec<i64> = conn
            .prepare("SELECT id FROM jobs WHERE state = 'running'")?
            .query_map([], |r| r.get(0))?
            .collect::<rusqlite::Result<_>>()?;
        conn.execute(
            "UPDATE jobs SET state = 'interrupted', finished_s = ?1,
                error = 'the service stopped while the job ran; queue it again'
             WHERE state = 'running'",
            params![now_s()],
        )?;
        if !interrupted.is_empty() {
            tracing::warn!(
                "{} job(s) were running when the service last stopped: marked interrupted",
                interrupted.len()
            );
        }
        Ok(Self {
            conn: Mutex::new(conn),
            interrupted,
        })
    }

    /// The jobs this opening found running and marked interrupted.
    pub fn interrupted_at_open(&self) -> &[i64] {
        &self.interrupted
    }

    /// Say why job `id` ended as it did (its state and times stay).
    pub fn set_error(&self, id: i64, error: &str) -> Result<()> {
        self.conn().execute(
            "UPDATE jobs SET error = ?2 WHERE id = ?1",
            params![id, error],
        )?;
        Ok(())
    }

    fn conn(&self) -> std::sync::MutexGuard<'_, Connection> {
        // A panic while the lock was held leaves SQLite itself consistent.
        self.conn.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Queue a job; its id.
    pub fn insert(&self, kind: &str, request: &serde_json::Value, out: &str) -> Result<i64> {
        let conn = self.conn();
        conn.execute(
            "INSERT INTO jobs (kind, state, request, out, created_s) VALUES (?1, 'queued', ?2, ?3, ?4)",
            params![kind, request.to_string(), out, now_s()],
        )?;
        Ok(conn.last_insert_rowid())
    }

    /// Move job `id` to `state` (stamping the start or the end), with its error and
    /// summary when it ends.
    pub fn set_state(
        &self,
        id: i64,
        state: JobState,
        error: Option<&str>,
        summary: Option<&serde_json::Value>,
    ) -> Result<()> {
        let conn = self.conn();
        let now = now_s();
        if state == JobState::Running {
            conn.execute(
                "UPDATE jobs SET state = ?2, started_s = ?3 WHERE id = ?1",
                params![id, state.as_str(), now],
            )?;
        } else {
            conn.execute(
                "UPDATE jobs SET state = ?2, finished_s = ?3, error = ?4, summary = ?5 WHERE id = ?1",
                params![
                    id,
                    state.as_str(),
                    now,
                    error,
                    summary.map(|s| s.to_string())
                ],
            )?;
        }
        Ok(())
    }

    /// Job `id`, if there is one.
    pub fn get(&self, id: i64) -> Result<Option<Job>> {
        self.conn()
            .query_row(&format!("{SELECT} WHERE id = ?1"), params![id], row)
            .optional()
            .map_err(Into::into)
    }

    /// Every job, newest first.
    pub fn list(&self) -> Result<Vec<Job>> {
        let conn = self.conn();
        let mut stmt = conn.prepare(&format!("{SELECT} ORDER BY id DESC"))?;
        let jobs = stmt.query_map([], row)?.collect::<Result<_, _>>()?;
        Ok(jobs)
    }

    /// The queued jobs' ids, oldest first.
    pub fn queued(&self) -> Result<Vec<i64>> {
        let conn = self.conn();
        let mut stmt = conn.prepare("SELECT id FROM jobs WHERE state = 'queued' ORDER BY id")?;
        let ids = stmt
            .query_map([], |r| r.get(0))?
            .collect::<Result<_, _>>()?;
        Ok(ids)
    }
}

const SELECT: &str = "SELECT id, kind, state, request, out, created_s, started_s, finished_s, error, summary FROM jobs";

fn row(r: &rusqlite::Row<'_>) -> rusqlite::Result<Job> {
    let json = |k: usize| -> rusqlite::Result<Option<serde_json::Value>> {
        let text: Option<String> = r.get(k)?;
        Ok(text.and_then(|t| serde_json::from_str(&t).ok()))
    };
    let state: String = r.get(2)?;
    Ok(Job::with_reports(Job {
        id: r.get(0)?,
        kind: r.get(1)?,
        state: JobState::parse(&state).unwrap_or(JobState::Failed),
        request: json(3)?.unwrap_or(serde_json::Value::Null),
        out: r.get(4)?,
        created_s: r.get(5)?,
        started_s: r.get(6)?,
        finished_s: r.get(7)?,
        error: r.get(8)?,
        summary: json(9)?,
        reports: vec![],
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_job_moves_through_its_states_and_a_restart_marks_a_running_one_interrupted() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("jobs.sqlite");
        let store = Store::open(&path).unwrap();
        let request = serde_json::json!({"kind": "acquire", "out": "/tmp/x"});
        let a = store.insert("acquire", &request, "/tmp/x").unwrap();
        let b = store.insert("acquire", &request, "/tmp/y").unwrap();
        assert_eq!(store.queued().unwrap(), vec![a, b]);
        store.set_state(a, JobState::Running, None, None).unwrap();
        let job = store.get(a).unwrap().unwrap();
        assert_eq!(job.state, JobState::Running);
        assert!(job.started_s.is_some() && job.finished_s.is_none());
        assert_eq!(job.request, request);
        drop(store);
        // Killed while `a` ran: a new service finds it interrupted, `b` still queued.
        let store = Store::open(&path).unwrap();
        let job = store.get(a).unwrap().unwrap();
        assert_eq!(job.state, JobState::Interrupted);
        assert!(job.error.unwrap().contains("service stopped"));
        assert_eq!(store.queued().unwrap(), vec![b]);
        let summary = serde_json::json!({"frames_in_dataset": 441});
        store
            .set_state(b, JobState::Done, None, Some(&summary))
            .unwrap();
        let job = store.get(b).unwrap().unwrap();
        assert_eq!((job.state, job.summary), (JobState::Done, Some(summary)));
        assert_eq!(store.list().unwrap().len(), 2);
        assert!(store.get(99).unwrap().is_none());
    }
}
