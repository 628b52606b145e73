//! The certificate: one self-contained HTML file (its plots inline as SVG, no network,
//! no script), which a browser prints to PDF: the results with U and k, the uncertainty
//! budget, the report's tables and plots, and the traceability block.

use super::ReportError;
use crate::calibrate::json::{CalibrationJson, Quantity};
use crate::calibrate::table::decimals;
use pulldown_cmark::{html, Event, Options, Parser, Tag, TagEnd};
use std::fmt::Write as _;
use std::path::Path;

/// Text for HTML.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Markdown as HTML, with each image of a file in `dir` inline (its SVG).
fn body(md: &str, dir: &Path) -> Result<String, ReportError> {
    let mut events = Vec::new();
    let mut in_image = false;
    for ev in Parser::new_ext(md, Options::ENABLE_TABLES) {
        match ev {
            Event::Start(Tag::Image { dest_url, .. }) => {
                let path = dir.join(dest_url.as_ref());
                let svg = std::fs::read_to_string(&path).map_err(super::err(&path))?;
                // The SVG element alone: no XML declaration inside HTML.
                let start = svg.find("<svg").unwrap_or(0);
                let svg = svg.get(start..).unwrap_or(&svg);
                events.push(Event::Html(format!("<figure>{svg}</figure>").into()));
                in_image = true;
            }
            Event::End(TagEnd::Image) => in_image = false,
            _ if in_image => {}
            ev => events.push(ev),
        }
    }
    let mut out = String::new();
    html::push_html(&mut out, events.into_iter());
    Ok(out)
}

/// `x` to two significant figures (an uncertainty).
fn sig(x: f64) -> String {
    let d = decimals(x);
    format!("{x:.d$}")
}

/// One row of the results table.
fn row(out: &mut String, name: &str, q: &Quantity, unit: &str) {
    // The value to the last decimal its U shows.
    let d = decimals(q.expanded_unc);
    let _ = writeln!(
        out,
        "<tr><td>{}</td><td class=n>{:.d$}</td><td class=n>{}</td><td class=n>{:.2}</td>\
         <td class=n>{}</td><td>{}</td></tr>",
        esc(name),
        q.value,
        sig(q.expanded_unc),
        q.k,
        sig(q.std_unc),
        esc(unit)
    );
}

/// The results of every entry of `cal`: value, U, k and u of each intrinsic property.
fn results(cal: &CalibrationJson) -> String {
    let mut o = String::new();
    let per = format!("{} per m/s²", cal.units);
    for e in &cal.by_rate {
        let title = match e.rate_hz {
            Some(r) => format!("Rotation at {r} Hz"),
            None => "Static".to_string(),
        };
        let _ = writeln!(
            o,
            "<h3>{}</h3>\n<table class=results><thead><tr><th>property</th><th>value</th>\
             <th>U (95 %)</th><th>k</th><th>u</th><th>unit</th></tr></thead><tbody>",
            esc(&title)
        );
        let i = &e.intrinsic;
        for (n, q) in [
            ("s_u", &i.sensitivity.u),
            ("s_v", &i.sensitivity.v),
            ("s_w", &i.sensitivity.w),
        ] {
            row(&mut o, n, q, &per);
        }
        for (n, q) in [
            ("φ_uv", &i.angle_deg.uv),
            ("φ_vw", &i.angle_deg.vw),
            ("φ_wu", &i.angle_deg.wu),
        ] {
            row(&mut o, n, q, "°");
        }
        if let Some(off) = &i.offset {
            for (n, q) in [("O_u", &off.u), ("O_v", &off.v), ("O_w", &off.w)] {
                row(&mut o, n, q, &cal.units);
            }
        }
        o.push_str("</tbody></table>\n");
    }
    o
}

const STYLE: &str = "body{font-family:sans-serif;max-width:60em;margin:2em auto;color:#111}\
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #999}\
table{border-collapse:collapse;margin:0.5em 0;font-size:0.85em}\
td,th{border:1px solid #bbb;padding:2px 6px}td.n{text-align:right;font-variant-numeric:tabular-nums}\
pre{font-size:0.7em;white-space:pre-wrap}figure{margin:0.5em 0;page-break-inside:avoid}\
figure svg{max-width:100%;height:auto}table,tr{page-break-inside:avoid}\
@media print{body{margin:0}}";

/// The certificate for `cal`, from the report's Markdown `md` (its plots in `dir`, its
/// traceability block last) and the terminal summary with the budget `summary`.
pub fn certificate(
    cal: &CalibrationJson,
    source: &str,
    md: &str,
    dir: &Path,
    summary: &str,
) -> Result<String, ReportError> {
    let mut o = String::new();
    let _ = write!(
        o,
        "<!DOCTYPE html>\n<html lang=en><head><meta charset=utf-8>\
         <title>rotacal calibration: {src}</title><style>{STYLE}</style></head><body>\n\
         <h1>Calibration of a triaxial accelerometer: {src}</h1>\n\
         <p>Method {method}, g_loc = {g} m/s², readings in {units}. U is the expanded \
         uncertainty for a coverage probability of about 95 %, U = k·u, with k from each \
         property's effective degrees of freedom.</p>\n<h2 id=results>Results</h2>\n",
        src = esc(source),
        method = esc(cal.method.as_str()),
        g = cal.g_loc,
        units = esc(&cal.units)
    );
    o.push_str(&results(cal));
    let _ = write!(
        o,
        "<h2 id=budget>Uncertainty budget</h2>\n<pre>{}</pre>\n<h2>Report</h2>\n",
        esc(summary)
    );
    o.push_str(&body(md, dir)?);
    o.push_str("</body></html>\n");
    Ok(o)
}
