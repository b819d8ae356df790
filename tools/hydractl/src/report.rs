//! `hydractl model report`: one self-contained HTML page whose plots show
//! where the model fails and which effect is missing.

use std::fmt::Write as _;
use std::ops::Range;
use std::path::Path;

use anyhow::{anyhow, Context, Result};
use hydractl_ident::greybox::{self, FitOptions, Model, Signals};
use plotters::prelude::*;

/// Points per plotted series: enough to see every feature of a 1 kHz record.
const MAX_POINTS: usize = 2500;
const WIDTH: u32 = 900;
const HEIGHT: u32 = 260;

struct Series {
    label: String,
    points: Vec<(f64, f64)>,
    color: RGBColor,
}

fn series(label: &str, points: Vec<(f64, f64)>, color: RGBColor) -> Series {
    Series {
        label: label.to_owned(),
        points,
        color,
    }
}

fn stride(range: &Range<usize>) -> usize {
    (range.len() / MAX_POINTS).max(1)
}

fn extent(all: &[&Series], extra: &[f64]) -> (Range<f64>, Range<f64>) {
    let mut x = (f64::INFINITY, f64::NEG_INFINITY);
    let mut y = (f64::INFINITY, f64::NEG_INFINITY);
    for s in all {
        for (a, b) in s.points.iter().filter(|(a, b)| a.is_finite() && b.is_finite()) {
            x = (x.0.min(*a), x.1.max(*a));
            y = (y.0.min(*b), y.1.max(*b));
        }
    }
    for v in extra {
        y = (y.0.min(*v), y.1.max(*v));
    }
    if !x.0.is_finite() {
        x = (0.0, 1.0);
        y = (0.0, 1.0);
    }
    let pad = ((y.1 - y.0) * 0.05).max(1e-12);
    // Headroom for the legend, a line per series, so that it sits above
    // the data rather than on it.
    let headroom = pad + (y.1 - y.0).max(1e-12) * 0.12 * all.len() as f64;
    let xpad = if x.1 > x.0 { 0.0 } else { 1.0 };
    (x.0 - xpad..x.1 + xpad, y.0 - pad..y.1 + headroom)
}

/// A chart as an SVG string: lines, or dots when `dots`, and dashed
/// horizontal lines at ± `band` when given (a test's confidence bounds).
fn chart(title: &str, x_label: &str, y_label: &str, all: &[Series], dots: bool, band: Option<f64>) -> Result<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (WIDTH, HEIGHT)).into_drawing_area();
        let draw = |e: String| anyhow!("drawing `{title}`: {e}");
        root.fill(&WHITE).map_err(|e| draw(e.to_string()))?;
        let refs: Vec<&Series> = all.iter().collect();
        let extra: Vec<f64> = band.map(|b| vec![-b, b]).unwrap_or_default();
        let (xr, yr) = extent(&refs, &extra);
        let mut c = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 15))
            .margin(8)
            .x_label_area_size(32)
            .y_label_area_size(60)
            .build_cartesian_2d(xr.clone(), yr)
            .map_err(|e| draw(e.to_string()))?;
        c.configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .light_line_style(WHITE.mix(0.0))
            .draw()
            .map_err(|e| draw(e.to_string()))?;
        for s in all {
            let color = s.color;
            let points = s.points.iter().copied().filter(|(a, b)| a.is_finite() && b.is_finite());
            if dots && band.is_some() {
                // A correlation by lag: a stem per lag, read against the bounds.
                let points: Vec<(f64, f64)> = points.collect();
                c.draw_series(
                    points
                        .iter()
                        .map(|&(x, y)| PathElement::new(vec![(x, 0.0), (x, y)], color.stroke_width(2))),
                )
                .map_err(|e| draw(e.to_string()))?;
                c.draw_series(points.into_iter().map(|p| Circle::new(p, 3, color.filled())))
                    .map_err(|e| draw(e.to_string()))?
                    .label(s.label.clone())
                    .legend(move |(x, y)| Circle::new((x + 8, y), 3, color.filled()));
            } else if dots {
                c.draw_series(points.map(|p| Circle::new(p, 1, color.mix(0.5).filled())))
                    .map_err(|e| draw(e.to_string()))?
                    .label(s.label.clone())
                    .legend(move |(x, y)| Circle::new((x + 8, y), 3, color.filled()));
            } else {
                c.draw_series(LineSeries::new(points, color.stroke_width(1)))
                    .map_err(|e| draw(e.to_string()))?
                    .label(s.label.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2)));
            }
        }
        if let Some(b) = band {
            for level in [-b, b] {
                c.draw_series(DashedLineSeries::new(
                    vec![(xr.start, level), (xr.end, level)],
                    5,
                    3,
                    RED.stroke_width(1),
                ))
                .map_err(|e| draw(e.to_string()))?;
            }
        }
        finish(&mut c, &root).map_err(draw)?;
    }
    Ok(svg)
}

/// The report's charts: both axes in f64.
type Plane = Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>;

/// The legend, and the drawing written out.
fn finish<'a, 'b: 'a>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Plane>,
    root: &DrawingArea<SVGBackend<'b>, plotters::coord::Shift>,
) -> Result<(), String> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK.mix(0.3))
        .draw()
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())
}

/// Bars per step, one colour per output, labelled by the step's name.
fn bar_chart(title: &str, steps: &[String], outputs: &[(&str, Vec<f64>, RGBColor)]) -> Result<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (WIDTH, HEIGHT + 40)).into_drawing_area();
        let draw = |e: String| anyhow!("drawing `{title}`: {e}");
        root.fill(&WHITE).map_err(|e| draw(e.to_string()))?;
        // Each output as a share of its first step's (the baseline's), so
        // that an angle's NRMSE of 0.002 shows beside pressures' of 0.2.
        let shares: Vec<Vec<f64>> = outputs
            .iter()
            .map(|(_, values, _)| {
                let first = values
                    .iter()
                    .copied()
                    .find(|v| v.is_finite() && *v > 0.0)
                    .unwrap_or(f64::NAN);
                values.iter().map(|v| 100.0 * v / first).collect()
            })
            .collect();
        let top = shares
            .iter()
            .flatten()
            .copied()
            .filter(|v| v.is_finite())
            .fold(100.0_f64, f64::max)
            * 1.4;
        let n = steps.len();
        let mut c = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 15))
            .margin(8)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.5..n as f64 - 0.5, 0.0..top)
            .map_err(|e| draw(e.to_string()))?;
        let label = |x: &f64| {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < n {
                steps[i as usize].clone()
            } else {
                String::new()
            }
        };
        c.configure_mesh()
            .disable_x_mesh()
            .x_labels(n.max(2) * 2 + 1)
            .x_label_formatter(&label)
            .y_desc("% of the baseline's validation NRMSE")
            .light_line_style(WHITE.mix(0.0))
            .draw()
            .map_err(|e| draw(e.to_string()))?;
        let width = 0.7 / outputs.len().max(1) as f64;
        for (j, ((name, values, color), shares)) in outputs.iter().zip(&shares).enumerate() {
            let color = *color;
            let offset = -0.35 + width * j as f64;
            c.draw_series(shares.iter().enumerate().filter(|(_, v)| v.is_finite()).map(|(i, v)| {
                let x = i as f64 + offset;
                Rectangle::new([(x, 0.0), (x + width * 0.9, *v)], color.filled())
            }))
            .map_err(|e| draw(e.to_string()))?
            .label(*name)
            .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 12, y + 4)], color.filled()));
            // Centred over its bar and standing on it, not overlapping its top.
            let value_style =
                TextStyle::from(("sans-serif", 11).into_font()).pos(plotters::style::text_anchor::Pos::new(
                    plotters::style::text_anchor::HPos::Center,
                    plotters::style::text_anchor::VPos::Bottom,
                ));
            c.draw_series(
                values
                    .iter()
                    .zip(shares)
                    .enumerate()
                    .filter(|(_, (_, share))| share.is_finite())
                    .map(|(i, (v, share))| {
                        let x = i as f64 + offset + width * 0.45;
                        Text::new(format!("{v:.4}"), (x, *share + 0.01 * top), value_style.clone())
                    }),
            )
            .map_err(|e| draw(e.to_string()))?;
        }
        finish(&mut c, &root).map_err(draw)?;
    }
    Ok(svg)
}

const MEASURED: RGBColor = RGBColor(40, 40, 40);
const MODEL: RGBColor = RGBColor(220, 90, 20);
const SECOND: RGBColor = RGBColor(30, 110, 200);

pub fn write(signals: &Signals, model: &Model, options: FitOptions, out: &Path) -> Result<()> {
    write_with(signals, model, None, options, out)?;
    crate::emit(&format!("report written to {}\n", out.display()))
}

/// [`write`], with `model`'s diagnosis on `signals` where the caller has
/// it already (`model learn`'s last).
pub fn write_with(
    signals: &Signals,
    model: &Model,
    diagnosis: Option<&greybox::Diagnosis>,
    options: FitOptions,
    out: &Path,
) -> Result<()> {
    let effects = model.effects()?;
    let comparison = greybox::compare(&model.plant, &effects, signals, options.estimation_fraction);
    let diagnosed;
    let diagnosis = match diagnosis {
        Some(d) => d,
        None => {
            let progress = crate::progress::Progress::new("model report", false);
            progress.step("diagnosing", 0, 1);
            diagnosed = greybox::diagnose_with(signals, Some(model), options, &progress)?;
            &diagnosed
        }
    };
    let p = &comparison.prediction;
    let v = comparison.validation.clone();
    let step = stride(&v);
    let at = |y: &[f64], scale: f64| -> Vec<(f64, f64)> {
        v.clone().step_by(step).map(|k| (signals.t[k], y[k] * scale)).collect()
    };
    let residual = |y: &[f64], yhat: &[f64], scale: f64| -> Vec<f64> {
        (0..signals.len()).map(|k| (y[k] - yhat[k]) * scale).collect()
    };
    let bar = 1e-5;
    let r_a = residual(&signals.p_a, &p.p_a, bar);
    let r_b = residual(&signals.p_b, &p.p_b, bar);
    let r_theta = residual(&signals.theta, &p.theta, 1.0);
    let against = |x: &[f64], r: &[f64]| -> Vec<(f64, f64)> { v.clone().step_by(step).map(|k| (x[k], r[k])).collect() };

    let mut figures: Vec<(String, String)> = Vec::new();
    let mut add = |caption: &str, svg: Result<String>| -> Result<()> {
        figures.push((caption.to_owned(), svg?));
        Ok(())
    };
    let hydraulic = signals.parts().contains(&greybox::Part::Hydraulic);
    let outputs = [
        (
            "p_a",
            "Chamber pressure A, measured and model (validation segment).",
            signals.p_a.as_slice(),
            p.p_a.as_slice(),
            bar,
            "bar",
        ),
        (
            "p_b",
            "Chamber pressure B.",
            signals.p_b.as_slice(),
            p.p_b.as_slice(),
            bar,
            "bar",
        ),
        (
            "theta",
            "Angle, as the encoder reports it.",
            signals.theta.as_slice(),
            p.theta.as_slice(),
            1.0,
            "rad",
        ),
    ];
    for (name, caption, measured, modelled, scale, unit) in outputs {
        if name != "theta" && !hydraulic {
            continue;
        }
        add(
            caption,
            chart(
                &format!("{name}: measured against model"),
                "t [s]",
                unit,
                &[
                    series("measured", at(measured, scale), MEASURED),
                    series("model", at(modelled, scale), MODEL),
                ],
                false,
                None,
            ),
        )?;
    }
    if hydraulic {
        add(
            "Residuals over time: structure here is what the model misses.",
            chart(
                "pressure residuals",
                "t [s]",
                "bar",
                &[
                    series("p_a", at(&r_a, 1.0), MODEL),
                    series("p_b", at(&r_b, 1.0), SECOND),
                ],
                false,
                None,
            ),
        )?;
    }
    add(
        if hydraulic {
            ""
        } else {
            "Angle residual over time: structure here is what the model misses."
        },
        chart(
            "angle residual",
            "t [s]",
            "rad",
            &[series("theta", at(&r_theta, 1.0), MODEL)],
            false,
            None,
        ),
    )?;
    if hydraulic {
        add(
            "Pressure residual against the command: a dead-zone shows as a band near u = 0, saturation at the ends, asymmetric gain as a tilt on one side only.",
            chart(
                "p_a residual vs command",
                "u",
                "bar",
                &[series("p_a", against(&signals.u, &r_a), MODEL)],
                true,
                None,
            ),
        )?;
    } else if signals.has_command {
        add(
            "Angle residual against the command: a dead-zone or a null offset shows as a band near u = 0, saturation at the ends.",
            chart(
                "theta residual vs command",
                "u",
                "rad",
                &[series("theta", against(&signals.u, &r_theta), MODEL)],
                true,
                None,
            ),
        )?;
    }
    add(
        "Angle residual against velocity: friction shows as a step at zero velocity, backlash as a jump between directions.",
        chart(
            "theta residual vs velocity",
            "velocity [rad/s]",
            "rad",
            &[series("theta", against(&signals.velocity, &r_theta), MODEL)],
            true,
            None,
        ),
    )?;
    add(
        "Angle residual against angle: a gravity load shows as a sine, a coarse encoder as a sawtooth.",
        chart(
            "theta residual vs angle",
            "theta [rad]",
            "rad",
            &[series("theta", against(&signals.theta, &r_theta), MODEL)],
            true,
            None,
        ),
    )?;
    for t in &comparison.residual_tests {
        let points: Vec<(f64, f64)> = t
            .values
            .iter()
            .enumerate()
            .map(|(i, r)| ((t.first_lag + i as i64) as f64, *r))
            .collect();
        let caption = format!(
            "{} of the {} residual: max |r| {:.3} at lag {} against the 99% bound {:.3} ({}): {}.",
            t.test.replace('_', " "),
            t.output,
            t.max_abs,
            t.lag_of_max,
            t.bound,
            t.outcome(),
            t.note
        );
        add(
            &caption,
            chart(
                &format!("{} {}", t.output, t.test.replace('_', " ")),
                "lag [samples]",
                "r",
                &[series(&t.output, points, MODEL)],
                true,
                Some(t.bound),
            ),
        )?;
    }
    // The model's history comes first in the page: the fall of the error
    // is what the report is for.
    let mut history: Vec<(String, String)> = Vec::new();
    if model.history.len() > 1 {
        let names: Vec<String> = model.history.iter().map(|s| s.step.clone()).collect();
        let mut bars = Vec::new();
        for (output, color) in [("pressures", SECOND), ("theta", MODEL)] {
            let values: Vec<f64> = model
                .history
                .iter()
                .map(|s| s.validation_nrmse.get(output).copied().unwrap_or(f64::NAN))
                .collect();
            if values.iter().any(|v| v.is_finite()) {
                bars.push((output, values, color));
            }
        }
        history.push((
            format!(
                "The error falling, step by step ({}): each step's validation NRMSE on the data it was fitted on, \
                 as a share of the baseline's (the figure on a bar is the NRMSE itself).",
                names.join(" → ")
            ),
            bar_chart("validation NRMSE per step of the model's history", &names, &bars)?,
        ));
        // Each step's residual against the one before it, where the model
        // file kept the models the steps left.
        for pair in model.history.windows(2) {
            let (Some(before), Some(after)) = (pair[0].model(), pair[1].model()) else {
                continue;
            };
            let predict = |(plant, effects): &(hydractl_plant::PlantParams, hydractl_plant::Effects)| {
                greybox::predict(plant, effects, signals, v.clone())
            };
            let (p0, p1) = (predict(&before), predict(&after));
            let part = hydractl_plant::EffectKind::from_name(&pair[1].step)
                .ok()
                .and_then(|kind| signals.part_for(kind).ok());
            let (output, measured, y0, y1, scale, unit) = if part == Some(greybox::Part::Hydraulic) {
                ("p_a", &signals.p_a, p0.p_a, p1.p_a, bar, "bar")
            } else {
                ("theta", &signals.theta, p0.theta, p1.theta, 1.0, "rad")
            };
            let r0 = residual(measured, &y0, scale);
            let r1 = residual(measured, &y1, scale);
            let together = match &pair[1].together_with {
                Some(other) => format!(" (with {other}: neither was significant alone, the two together were)"),
                None => String::new(),
            };
            history.push((
                format!(
                    "Adding {}{together}: the {output} residual before the step (grey) and after it (colour).",
                    pair[1].step
                ),
                chart(
                    &format!("{output} residual, {} → {}", pair[0].step, pair[1].step),
                    "t [s]",
                    unit,
                    &[
                        series(
                            &format!("before ({})", pair[0].step),
                            at(&r0, 1.0),
                            RGBColor(150, 150, 150),
                        ),
                        series(&format!("after (+{})", pair[1].step), at(&r1, 1.0), MODEL),
                    ],
                    false,
                    None,
                )?,
            ));
        }
    }

    let mut html = String::from(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>hydractl model report</title>\
         <style>body{font-family:sans-serif;max-width:960px;margin:2em auto;color:#222}\
         table{border-collapse:collapse}td,th{padding:2px 8px;border-bottom:1px solid #ddd;text-align:left}\
         figure{margin:1em 0}figcaption{color:#555;font-size:90%}</style></head><body>",
    );
    let _ = write!(
        html,
        "<h1>Model against measurements</h1><p>Data: <code>{}</code>; validation {:.1}–{:.1} s.<br>Method: {}.</p>",
        escape(&signals.source),
        comparison.validation_start_s,
        comparison.validation_end_s,
        escape(&comparison.method)
    );
    let _ = write!(html, "<h2>Verdict</h2><p><b>{}</b></p>", prose(&diagnosis.verdict));
    if !history.is_empty() {
        html += "<h2>The model, step by step</h2>";
        push_figures(&mut html, &history);
    }
    html += "<h2>What this record can show</h2><ul>";
    for part in &diagnosis.parts {
        let _ = write!(html, "<li>fitted: {}</li>", escape(part.describe()));
    }
    for n in &diagnosis.not_judged {
        let _ = write!(html, "<li>not judged: <b>{}</b>: {}</li>", n.effect, escape(&n.reason));
    }
    if let Some(said) = signals.gaps_said() {
        let _ = write!(html, "<li>{}</li>", escape(&said));
    }
    html += "</ul>";
    html += "<h2>Fit per output</h2><table><tr><th>output</th><th>fit %</th><th>NRMSE</th></tr>";
    for o in &comparison.outputs {
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{:.2}</td><td>{:.4}</td></tr>",
            o.output, o.fit_percent, o.nrmse
        );
    }
    html += "</table><h2>By sub-model and regime</h2><table><tr><th>part</th><th>NRMSE</th></tr>";
    for (name, value) in &comparison.submodels {
        let _ = write!(html, "<tr><td>{name}</td><td>{value:.4}</td></tr>");
    }
    let measured = greybox::measured_outputs(signals);
    html += "</table><br><table><tr><th>regime</th><th>samples</th>";
    for output in &measured {
        let _ = write!(html, "<th>{output}</th>");
    }
    html += "</tr>";
    for r in &comparison.regimes {
        let _ = write!(html, "<tr><td>{}</td><td>{}</td>", r.regime, r.samples);
        for output in &measured {
            let _ = write!(
                html,
                "<td>{:.4}</td>",
                r.nrmse.get(*output).copied().unwrap_or(f64::NAN)
            );
        }
        html += "</tr>";
    }
    html += "</table><h2>Diagnosis</h2><table><tr><th>effect</th><th>output</th><th>before</th><th>after</th><th>significant</th><th>evidence</th></tr>";
    for c in &diagnosis.candidates {
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{}</td><td>{:.4}</td><td>{:.4}</td><td>{}</td><td>{}</td></tr>",
            c.effect,
            c.output,
            c.validation_nrmse_before,
            c.validation_nrmse_after,
            if c.significant { "yes" } else { "no" },
            prose(&c.evidence)
        );
    }
    html += "</table><h2>Plots</h2>";
    push_figures(&mut html, &figures);
    html += "</body></html>\n";
    std::fs::write(out, html).with_context(|| format!("writing the report to {}", out.display()))
}

fn push_figures(html: &mut String, figures: &[(String, String)]) {
    for (caption, svg) in figures {
        let _ = write!(
            html,
            "<figure>{svg}<figcaption>{}</figcaption></figure>",
            escape(caption)
        );
    }
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// The tools' plain text as HTML: escaped, and a name between backticks
/// (an effect, a parameter) set as code, as a terminal reader sees it
/// quoted. An unpaired backtick stays as it is.
fn prose(text: &str) -> String {
    let pieces: Vec<String> = escape(text).split('`').map(str::to_owned).collect();
    let paired = pieces.len() % 2 == 1;
    let mut html = String::new();
    for (i, piece) in pieces.iter().enumerate() {
        match (i % 2, paired || i + 1 < pieces.len()) {
            (1, true) => {
                html += "<code>";
                html += piece;
                html += "</code>";
            }
            (1, false) => {
                html.push('`');
                html += piece;
            }
            _ => html += piece,
        }
    }
    html
}

#[cfg(test)]
mod tests {
    use super::prose;

    #[test]
    fn names_in_backticks_are_set_as_code_and_the_rest_escaped() {
        assert_eq!(
            prose("add `time_delay`: p < 0.01 & `x`"),
            "add <code>time_delay</code>: p &lt; 0.01 &amp; <code>x</code>"
        );
        assert_eq!(prose("a lone ` stays"), "a lone ` stays");
    }
}
