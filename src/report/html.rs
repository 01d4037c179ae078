//! The report page: headings, notes, tables and inline SVG figures, with its style inline.

use super::chart::{self, Axes, ChartError, Series};
use crate::daemon::replay::ReplaySummary;
use std::fmt::Write;

const STYLE: &str = "body{font-family:sans-serif;max-width:1000px;margin:1em auto;color:#222}\
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #bbb;padding:2px 8px;text-align:right}\
th{background:#eee}td:first-child,th:first-child{text-align:left}figure{margin:.5em 0}\
p.note{color:#555;font-style:italic}pre{background:#f6f6f6;padding:.5em;overflow-x:auto}";

pub(crate) struct Page {
    body: String,
    title: String,
}

impl Page {
    pub(crate) fn new(title: &str) -> Self {
        let mut body = String::new();
        let _ = write!(body, "<h1>{}</h1>", escape(title));
        Self {
            body,
            title: title.to_owned(),
        }
    }

    pub(crate) fn section(&mut self, heading: &str, text: &str) {
        let _ = write!(
            self.body,
            "<h2>{}</h2><p>{}</p>",
            escape(heading),
            escape(text)
        );
    }

    pub(crate) fn note(&mut self, text: &str) {
        let _ = write!(self.body, "<p class=\"note\">{}</p>", escape(text));
    }

    /// A figure with the chart, or a note saying there was nothing to draw. `data-series` names
    /// the series drawn, so that a reader (or a test) knows what the figure should hold.
    pub(crate) fn chart(
        &mut self,
        id: &str,
        axes: &Axes,
        series: &[Series],
    ) -> Result<(), ChartError> {
        match chart::svg(axes, series)? {
            Some(svg) => {
                let drawn: Vec<&str> = series
                    .iter()
                    .filter(|s| !s.points.is_empty())
                    .map(|s| s.name.as_str())
                    .collect();
                let _ = write!(
                    self.body,
                    "<figure id=\"{}\" data-series=\"{}\">{}</figure>",
                    escape(id),
                    escape(&drawn.join("|")),
                    strip_xml_declaration(&svg)
                );
            }
            None => self.note(&format!("{}: nothing to draw in this run.", axes.title)),
        }
        Ok(())
    }

    pub(crate) fn table(&mut self, header: &[&str], rows: &[Vec<String>]) {
        self.body.push_str("<table><tr>");
        for cell in header {
            let _ = write!(self.body, "<th>{}</th>", escape(cell));
        }
        self.body.push_str("</tr>");
        for row in rows {
            self.body.push_str("<tr>");
            for cell in row {
                let _ = write!(self.body, "<td>{}</td>", escape(cell));
            }
            self.body.push_str("</tr>");
        }
        self.body.push_str("</table>");
    }

    /// The summary table in the paper's format, then the replay's own summary in full.
    pub(crate) fn summary(&mut self, summary: &ReplaySummary) {
        self.section("Summary", "Error statistics as the paper gives them (standard deviation per axis; attitude in mrad), the integrity monitor's work, and how honest the velocity sent to the autopilot was.");
        let per_epoch = summary.outputs.planes as f64 / summary.outputs.epochs.max(1) as f64;
        let mut rows = vec![
            row("replayed", format!("{:.1} s", summary.duration_s)),
            row(
                "estimates / epochs",
                format!("{} / {}", summary.outputs.estimates, summary.outputs.epochs),
            ),
            row("planes per epoch", format!("{per_epoch:.1}")),
            row(
                "detections / exclusions",
                format!(
                    "{} / {}",
                    summary.outputs.detections, summary.outputs.exclusions
                ),
            ),
        ];
        if let Some(truth) = &summary.truth {
            rows.push(row(
                "velocity error std N E D (m/s)",
                triple(truth.velocity_std_ned, 4),
            ));
            rows.push(row(
                "velocity error RMS N E D (m/s)",
                triple(truth.velocity_rms_ned, 4),
            ));
            rows.push(row(
                "attitude error std R P Y (mrad)",
                triple(truth.attitude_std_mrad, 2),
            ));
            rows.push(row(
                "attitude error RMS R P Y (mrad)",
                triple(truth.attitude_rms_mrad, 2),
            ));
        }
        if let Some(view) = &summary.autopilot {
            rows.push(row(
                "valid ODOMETRY (quality >= 1)",
                format!("{} of {}", view.valid, view.estimates),
            ));
            let first = view
                .first_valid_after_s
                .map_or_else(|| "never".to_owned(), |s| format!("{s:.1} s"));
            rows.push(row("first valid after", first));
            rows.push(row("inside 3 sigma F R D", triple(view.inside_3_sigma, 3)));
            rows.push(row("NEES F R D (1 when honest)", triple(view.mean_nees, 2)));
            rows.push(row(
                "worst valid error (m/s)",
                format!("{:.3}", view.worst_valid_error_mps),
            ));
            rows.push(row("resets", view.resets.to_string()));
        }
        self.table(&["", "value"], &rows);
        let _ = write!(
            self.body,
            "<details><summary>replay summary</summary><pre>{}</pre></details>",
            escape(&summary.to_string())
        );
    }

    pub(crate) fn finish(self) -> String {
        format!(
            "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title>\
             <style>{STYLE}</style></head><body>{}</body></html>\n",
            escape(&self.title),
            self.body
        )
    }
}

fn row(name: &str, value: String) -> Vec<String> {
    vec![name.to_owned(), value]
}

fn triple(values: [f64; 3], decimals: usize) -> String {
    let [a, b, c] = values;
    format!("{a:.decimals$} {b:.decimals$} {c:.decimals$}")
}

/// An SVG document inlined in HTML must not carry its own XML declaration.
fn strip_xml_declaration(svg: &str) -> &str {
    match svg.strip_prefix("<?xml") {
        Some(rest) => rest
            .find("?>")
            .map_or(svg, |end| rest[end + 2..].trim_start()),
        None => svg,
    }
}

pub(crate) fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            _ => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_escaped_and_the_page_is_whole() {
        let mut page = Page::new("a <b> & \"c\"");
        page.note("x < y");
        let html = page.finish();
        assert!(html.contains("a &lt;b&gt; &amp; &quot;c&quot;"));
        assert!(html.contains("x &lt; y"));
        assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    }
}
