//! The metrics table of a scenario, laid out as the paper's Table 1: one row per metric, one
//! column per strategy x step count, as CSV, Markdown and JSON.

use serde::Serialize;

use super::Run;

/// Metric names and units, rows of the table.
pub const ROWS: [(&str, &str); 5] = [
    ("M1", "m^2"),
    ("M2", "m^2"),
    ("M3", "rad^2"),
    ("M4", "m^3"),
    ("M5", "m rad^2"),
];

/// One column of the JSON table.
#[derive(Debug, Clone, Serialize)]
pub struct Column {
    /// `sequential tractrix, K=1`.
    pub label: String,
    /// Strategy label.
    pub strategy: String,
    /// Straight pieces of the pull.
    pub steps: usize,
    /// Optimizer iterations (0 for sequential).
    pub iterations: usize,
    /// Whether every optimization met its stopping rule.
    pub converged: bool,
    /// Largest link length error over the run, m.
    pub length_residual: f64,
}

/// One row of the JSON table.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// `M1`..`M5`.
    pub metric: &'static str,
    /// Unit.
    pub unit: &'static str,
    /// One value per column.
    pub values: Vec<f64>,
}

/// The JSON table.
#[derive(Debug, Clone, Serialize)]
pub struct Table {
    /// Scenario title.
    pub title: String,
    /// Columns, in run order.
    pub columns: Vec<Column>,
    /// Rows M1..M5.
    pub rows: Vec<Row>,
}

impl Table {
    /// The table of a scenario's runs.
    pub fn new(title: &str, runs: &[Run]) -> Self {
        Self {
            title: title.to_string(),
            columns: runs
                .iter()
                .map(|r| Column {
                    label: r.label(),
                    strategy: r.strategy.label(),
                    steps: r.steps,
                    iterations: r.iterations,
                    converged: r.converged,
                    length_residual: r.length_residual,
                })
                .collect(),
            rows: ROWS
                .iter()
                .enumerate()
                .map(|(i, (metric, unit))| Row {
                    metric,
                    unit,
                    values: runs
                        .iter()
                        .map(|r| r.metrics.get(i + 1).unwrap_or(f64::NAN))
                        .collect(),
                })
                .collect(),
        }
    }

    /// CSV: a header `metric,unit,<labels>`, then one line per metric (labels quoted).
    pub fn csv(&self) -> String {
        let mut s = String::from("metric,unit");
        for c in &self.columns {
            s.push_str(&format!(",\"{}\"", c.label.replace('"', "\"\"")));
        }
        s.push('\n');
        for r in &self.rows {
            s.push_str(&format!("{},{}", r.metric, r.unit));
            for v in &r.values {
                s.push_str(&format!(",{v:e}"));
            }
            s.push('\n');
        }
        s
    }

    /// Markdown, values to four significant digits.
    pub fn markdown(&self) -> String {
        let mut s = format!("**{}**\n\n| metric | unit |", self.title);
        for c in &self.columns {
            s.push_str(&format!(" {} |", c.label));
        }
        s.push_str("\n| --- | --- |");
        for _ in &self.columns {
            s.push_str(" ---: |");
        }
        s.push('\n');
        for r in &self.rows {
            s.push_str(&format!("| {} | {} |", r.metric, r.unit));
            for v in &r.values {
                s.push_str(&format!(" {v:.4e} |"));
            }
            s.push('\n');
        }
        s
    }

    /// Pretty JSON.
    pub fn json(&self) -> Result<String, serde_json::Error> {
        serde_json::to_string_pretty(self)
    }
}
