"""The store's versioned schema: an ordered list of migrations, each applied in one transaction.

``MIGRATIONS[i]`` takes a database from schema version ``i`` to ``i + 1``; the ``schema_version`` table holds the
version a database is at (one row). Opening a database applies the migrations it lacks, one transaction each, so a
failure leaves it at the last whole version; a database newer than ``SCHEMA_VERSION`` is refused (this code does not
know its tables). Append a migration to change the schema; never edit one that has shipped.

The SQL is the same for SQLite and PostgreSQL: DOUBLE PRECISION (a REAL would be 4 bytes in PostgreSQL), BIGINT
(cycle indices of years of running), TEXT for JSON (lists, dicts: read only whole). Times ``*_at`` are wall-clock
Unix seconds when the row was written (retention keys on them); ``t_start_s`` is the acquisition time of the log.
"""

from __future__ import annotations

MIGRATIONS: tuple[tuple[str, ...], ...] = (
    # 0 -> 1: the tables
    (
        """CREATE TABLE engines (
            engine_id TEXT PRIMARY KEY,
            created_at DOUBLE PRECISION NOT NULL)""",
        # one row per distinct engine TOML an engine was run with; version counts from 1
        """CREATE TABLE model_versions (
            engine_id TEXT NOT NULL REFERENCES engines (engine_id),
            version BIGINT NOT NULL,
            toml_sha256 TEXT NOT NULL,
            engine_toml TEXT NOT NULL,
            registered_at DOUBLE PRECISION NOT NULL,
            PRIMARY KEY (engine_id, version))""",
        """CREATE TABLE cycles (
            engine_id TEXT NOT NULL REFERENCES engines (engine_id),
            cycle_index BIGINT NOT NULL,
            model_version BIGINT,
            t_start_s DOUBLE PRECISION,
            rpm_mean DOUBLE PRECISION,
            load_torque_nm DOUBLE PRECISION,
            load_power_kw DOUBLE PRECISION,
            imep_bar TEXT NOT NULL,
            pmax_bar TEXT NOT NULL,
            friction_balance_nm DOUBLE PRECISION,
            flags TEXT NOT NULL,
            extra TEXT,
            written_at DOUBLE PRECISION NOT NULL,
            PRIMARY KEY (engine_id, cycle_index))""",
        """CREATE TABLE estimates (
            engine_id TEXT NOT NULL REFERENCES engines (engine_id),
            cycle_index BIGINT NOT NULL,
            cylinder BIGINT NOT NULL,
            fmep_bar DOUBLE PRECISION,
            fmep_sigma_bar DOUBLE PRECISION,
            friction_torque_mean_nm DOUBLE PRECISION,
            friction_torque_sigma_nm DOUBLE PRECISION,
            coefficients TEXT NOT NULL,
            coefficient_sigmas TEXT NOT NULL,
            data_weight DOUBLE PRECISION,
            status TEXT NOT NULL,
            reason TEXT,
            flags TEXT NOT NULL,
            extra TEXT,
            written_at DOUBLE PRECISION NOT NULL,
            PRIMARY KEY (engine_id, cycle_index, cylinder))""",
        # the whole alert as JSON (doc) plus the columns a query selects on
        """CREATE TABLE alerts (
            engine_id TEXT NOT NULL REFERENCES engines (engine_id),
            alert_id BIGINT NOT NULL,
            cylinder BIGINT,
            kind TEXT NOT NULL,
            severity TEXT NOT NULL,
            state TEXT NOT NULL,
            raised_cycle BIGINT,
            doc TEXT NOT NULL,
            updated_at DOUBLE PRECISION NOT NULL,
            PRIMARY KEY (engine_id, alert_id))""",
        # every baseline saved is kept (a re-baseline is auditable); the newest is the one in force
        """CREATE TABLE baselines (
            engine_id TEXT NOT NULL REFERENCES engines (engine_id),
            seq BIGINT NOT NULL,
            doc TEXT NOT NULL,
            saved_at DOUBLE PRECISION NOT NULL,
            PRIMARY KEY (engine_id, seq))""",
    ),
    # 1 -> 2: retention deletes by age in batches (service.store.sql_store.SqlStore.apply_retention); without these
    # indexes each batch scans the whole table. Active alerts are listed on every dashboard refresh.
    (
        "CREATE INDEX cycles_written_at ON cycles (written_at)",
        "CREATE INDEX estimates_written_at ON estimates (written_at)",
        "CREATE INDEX alerts_state ON alerts (engine_id, state)",
    ),
    # 2 -> 3: runs (issue 28). Each start of the service is a run of each engine it serves; every row written names
    # its run, and a run numbers its cycles on from the last cycle the store holds, so a restart appends and never
    # replaces an earlier run's rows (the upserts only replace rows of their own run: a retried batch).
    # last_cycle: the newest cycle the run committed, so the numbering continues even after retention deleted the
    # cycles. Rows written before this version keep run_id NULL: "before runs were recorded".
    (
        """CREATE TABLE runs (
            engine_id TEXT NOT NULL REFERENCES engines (engine_id),
            run_id BIGINT NOT NULL,
            started_at DOUBLE PRECISION NOT NULL,
            first_cycle BIGINT NOT NULL,
            last_cycle BIGINT,
            model_version BIGINT,
            PRIMARY KEY (engine_id, run_id))""",
        "ALTER TABLE cycles ADD COLUMN run_id BIGINT",
        "ALTER TABLE estimates ADD COLUMN run_id BIGINT",
        "ALTER TABLE alerts ADD COLUMN run_id BIGINT",
        "ALTER TABLE baselines ADD COLUMN run_id BIGINT",
    ),
    # 3 -> 4: several serve processes on one database (issue 28 item 7, service/store/fleet.py). writers: the lease
    # of each engine id, held by the one process that writes it (writer: host, pid and a token of that start;
    # heartbeat_at on the database's own clock, so the boxes' clocks need not agree). engine_latest: each engine's
    # newest committed cycle and its engine friction figure, written in the transaction of every batch, so the
    # fleet view reads one row per engine instead of scanning cycles.
    (
        """CREATE TABLE writers (
            engine_id TEXT PRIMARY KEY REFERENCES engines (engine_id),
            writer TEXT NOT NULL,
            host TEXT NOT NULL,
            pid BIGINT NOT NULL,
            claimed_at DOUBLE PRECISION NOT NULL,
            heartbeat_at DOUBLE PRECISION NOT NULL)""",
        """CREATE TABLE engine_latest (
            engine_id TEXT PRIMARY KEY REFERENCES engines (engine_id),
            run_id BIGINT,
            cycle_index BIGINT NOT NULL,
            t_start_s DOUBLE PRECISION,
            written_at DOUBLE PRECISION NOT NULL,
            fmep_bar DOUBLE PRECISION,
            fmep_sigma_bar DOUBLE PRECISION,
            status TEXT,
            reason TEXT)""",
    ),
    # 4 -> 5: the monitor's carried state saved at a clean stop (service/monitor_snapshot.py), one row per engine: the
    # next run of the engine goes on from it instead of a warm-up (service/data_dir.py says when it may)
    (
        """CREATE TABLE monitor_states (
            engine_id TEXT PRIMARY KEY REFERENCES engines (engine_id),
            run_id BIGINT NOT NULL,
            model_version BIGINT NOT NULL,
            fingerprint TEXT NOT NULL,
            last_cycle BIGINT,
            saved_at DOUBLE PRECISION NOT NULL,
            doc TEXT NOT NULL)""",
    ),
)

SCHEMA_VERSION = len(MIGRATIONS)

VERSION_TABLE = "CREATE TABLE IF NOT EXISTS schema_version (version BIGINT NOT NULL)"
