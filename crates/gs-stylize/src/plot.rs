//! Line charts of a run's logs as PNG pictures: a title, axis labels with tick values, one
//! coloured curve per series and a legend beside the plot. They are drawn with plotters into
//! a memory bitmap, in Noto Sans from the `notosans` crate, so no system font is needed. The
//! y axis is logarithmic when the positive values span more than [`LOG_SPAN`].
//!
//! [`loss_chart`] is the stylization's `losses.png`; a base crate builds its own [`Chart`]
//! (base-mirage: the fit's PSNR).

use std::ops::Range;
use std::path::Path;
use std::sync::Once;

use image::RgbImage;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::outputs::StepLosses;
use crate::StylizeError;

/// Width of a chart, pixels.
pub const PLOT_WIDTH: u32 = 640;
/// Height of a chart, pixels.
pub const PLOT_HEIGHT: u32 = 420;
/// Width of the legend column at the right of a chart, pixels; curves are drawn left of it.
pub const LEGEND_WIDTH: u32 = 130;
/// Positive values whose largest is more than this many times their smallest (two decades)
/// are drawn on a log axis.
pub const LOG_SPAN: f64 = 100.0;
/// The weighted loss terms of a stylization step, in legend order.
pub const LOSS_TERMS: [&str; 4] = ["directional", "patch", "content", "background"];
/// Curve colours: the first for a chart's main series, then one per further series.
pub const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [23, 190, 207],
];

/// Font family the charts' text is registered under.
const FONT: &str = "sans-serif";
/// Pixel size of the title.
const TITLE_SIZE: u32 = 21;
/// Pixel size of the axis names.
const AXIS_NAME_SIZE: u32 = 16;
/// Pixel size of the tick values and the legend.
const TICK_SIZE: u32 = 14;
/// Height of the strip above the plot that holds the y axis' name, pixels.
const Y_NAME_HEIGHT: u32 = 24;
/// Height of one legend entry, pixels.
const LEGEND_ROW: u32 = 22;
/// Where the first legend entry is, pixels below the top of the legend column.
const LEGEND_TOP: u32 = 50;

/// One named curve: `(x, y)` points in drawing order.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    /// Its name in the legend.
    pub name: String,
    /// Its colour, RGB.
    pub color: [u8; 3],
    /// Its points; those the y axis cannot show (non-finite, or not positive on a log axis)
    /// are skipped and break the line.
    pub points: Vec<(f64, f64)>,
    /// Drawn dashed and over the others (the loss chart's total, which often lies on the
    /// largest term: both stay visible).
    pub dashed: bool,
}

/// A line chart: what [`Chart::render`] draws.
#[derive(Clone, Debug, PartialEq)]
pub struct Chart {
    /// The title above the plot.
    pub title: String,
    /// The name of the x axis.
    pub x_label: String,
    /// The name of the y axis.
    pub y_label: String,
    /// The curves, drawn in order (later ones on top) and listed in the legend in order.
    pub series: Vec<Series>,
}

/// How the y axis maps values.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum YScale {
    /// Evenly spaced values.
    Linear,
    /// Evenly spaced decades; only positive values are shown.
    Log,
}

impl YScale {
    /// Whether the point `(x, y)` can be drawn on this axis.
    pub fn shows(self, (x, y): (f64, f64)) -> bool {
        x.is_finite() && y.is_finite() && (self == YScale::Linear || y > 0.0)
    }
}

/// Why a chart could not be drawn (plotters' error for the memory bitmap).
type DrawError = DrawingAreaErrorKind<<BitMapBackend<'static> as DrawingBackend>::ErrorType>;
/// The drawing surface of a chart.
type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

impl Chart {
    /// The y axis the chart is drawn on: log when its positive finite values span more than
    /// [`LOG_SPAN`], else linear.
    pub fn y_scale(&self) -> YScale {
        let (lo, hi) = bounds(self.all_points(YScale::Log).map(|p| p.1));
        if hi / lo > LOG_SPAN {
            YScale::Log
        } else {
            YScale::Linear
        }
    }

    /// The legend: the name and colour of every series with at least one point the y axis
    /// shows, in order. Exactly these curves are drawn.
    pub fn legend(&self) -> Vec<(String, [u8; 3])> {
        let scale = self.y_scale();
        self.series
            .iter()
            .filter(|s| s.points.iter().any(|&p| scale.shows(p)))
            .map(|s| (s.name.clone(), s.color))
            .collect()
    }

    /// Draws the chart, [`PLOT_WIDTH`] x [`PLOT_HEIGHT`] pixels.
    pub fn render(&self) -> Result<RgbImage, StylizeError> {
        register_font();
        let mut buf = vec![255u8; (PLOT_WIDTH * PLOT_HEIGHT * 3) as usize];
        self.draw(
            BitMapBackend::with_buffer(&mut buf, (PLOT_WIDTH, PLOT_HEIGHT)).into_drawing_area(),
        )
        .map_err(|e| StylizeError::Plot(Box::new(e)))?;
        Ok(RgbImage::from_raw(PLOT_WIDTH, PLOT_HEIGHT, buf).expect("the buffer holds the chart"))
    }

    /// Draws the chart and writes it to `path` as a PNG (through [`gs_core::fs`]).
    pub fn write_png(&self, path: &Path) -> Result<(), StylizeError> {
        Ok(gs_core::image::save_rgb8_png(&self.render()?, path)?)
    }

    /// Draws the title, the plot and the legend on `root`.
    fn draw(&self, root: Area) -> Result<(), DrawError> {
        root.fill(&WHITE)?;
        let title = if self.legend().is_empty() {
            format!("{} (nothing to plot)", self.title)
        } else {
            self.title.clone()
        };
        let body = root.titled(&title, (FONT, TITLE_SIZE))?;
        let (plot, legend) = body.split_horizontally(PLOT_WIDTH - LEGEND_WIDTH);
        // The y axis' name stands above it: plotters' ab_glyph text cannot be rotated.
        let (y_name, plot) = plot.split_vertically(Y_NAME_HEIGHT);
        y_name.draw(&Text::new(
            self.y_label.as_str(),
            (12, 0),
            (FONT, AXIS_NAME_SIZE),
        ))?;
        let x = self.x_range();
        match self.y_scale() {
            YScale::Linear => self.draw_plot(&plot, x, self.linear_y_range())?,
            YScale::Log => self.draw_plot(&plot, x, self.log_y_range().log_scale())?,
        }
        draw_legend(&legend, &self.legend())?;
        root.present()
    }

    /// Draws the axes, the grid and the curves on `area` over `x` and `y`.
    fn draw_plot<Y>(&self, area: &Area, x: Range<f64>, y: Y) -> Result<(), DrawError>
    where
        Y: AsRangedCoord<Value = f64>,
        Y::CoordDescType: ValueFormatter<f64>,
    {
        let x_labels = ((x.end - x.start).round() as usize + 1).clamp(2, 8);
        let mut chart = ChartBuilder::on(area)
            .margin(12)
            .x_label_area_size(48)
            .y_label_area_size(64)
            .build_cartesian_2d(x, y)?;
        chart
            .configure_mesh()
            .x_desc(self.x_label.as_str())
            .axis_desc_style((FONT, AXIS_NAME_SIZE))
            .label_style((FONT, TICK_SIZE))
            .x_labels(x_labels)
            .y_labels(8)
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .light_line_style(RGBColor(238, 238, 238))
            .draw()?;
        // Thin lines where there are more points than pixels, so noise stays legible.
        let thin = |s: &Series| s.points.len() > area.dim_in_pixel().0 as usize;
        // Solid series first, dashed ones over them.
        let order = self.series.iter().filter(|s| !s.dashed);
        for s in order.chain(self.series.iter().filter(|s| s.dashed)) {
            let color = RGBColor(s.color[0], s.color[1], s.color[2]);
            let line = color.stroke_width(if thin(s) { 1 } else { 2 });
            for run in runs(&s.points, self.y_scale()) {
                match run.as_slice() {
                    [only] => chart.draw_series([Circle::new(*only, 3, color.filled())])?,
                    _ if s.dashed => chart.draw_series(DashedLineSeries::new(run, 8, 6, line))?,
                    _ => chart.draw_series(LineSeries::new(run, line))?,
                };
            }
        }
        Ok(())
    }

    /// Every point of every series that `scale` shows.
    fn all_points(&self, scale: YScale) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .filter(move |&p| scale.shows(p))
    }

    /// The x range of the drawn points, widened to a unit around a single value.
    fn x_range(&self) -> Range<f64> {
        let (lo, hi) = bounds(self.all_points(self.y_scale()).map(|p| p.0));
        match (lo.is_finite(), lo < hi) {
            (false, _) => 0.0..1.0,
            (true, false) => lo - 1.0..hi + 1.0,
            (true, true) => lo..hi,
        }
    }

    /// The y range of the drawn points with a 5% margin, widened around a single value.
    fn linear_y_range(&self) -> Range<f64> {
        let (lo, hi) = bounds(self.all_points(YScale::Linear).map(|p| p.1));
        if !lo.is_finite() {
            return 0.0..1.0;
        }
        let pad = if hi > lo {
            0.05 * (hi - lo)
        } else if lo != 0.0 {
            0.1 * lo.abs()
        } else {
            1.0
        };
        lo - pad..hi + pad
    }

    /// The y range of the drawn points, out to whole decades (and a hair beyond, so that
    /// plotters labels both ends).
    fn log_y_range(&self) -> Range<f64> {
        let (lo, hi) = bounds(self.all_points(YScale::Log).map(|p| p.1));
        let decade = |v: f64, round: fn(f64) -> f64| 10f64.powf(round(v.log10()));
        decade(lo, f64::floor) * 0.999..decade(hi, f64::ceil) * 1.001
    }
}

/// The stylization's loss chart: the total and every weighted term that is non-zero at some
/// step ([`LOSS_TERMS`] first, then any other in name order) against the step.
pub fn loss_chart(losses: &[StepLosses]) -> Chart {
    let total = Series {
        name: "total".into(),
        color: PALETTE[0],
        points: losses
            .iter()
            .map(|l| (l.step as f64, l.total as f64))
            .collect(),
        dashed: true,
    };
    let terms = term_names(losses)
        .into_iter()
        .zip(PALETTE[1..].iter().cycle())
        .map(|(name, &color)| term_series(losses, name, color))
        .filter(|s| s.points.iter().any(|&(_, y)| y.is_finite() && y != 0.0));
    Chart {
        title: "Stylization loss".into(),
        x_label: "step".into(),
        y_label: "weighted loss".into(),
        series: std::iter::once(total).chain(terms).collect(),
    }
}

/// Writes the loss chart of `losses` to `path` as a PNG.
pub fn write_loss_plot(path: &Path, losses: &[StepLosses]) -> Result<(), StylizeError> {
    loss_chart(losses).write_png(path)
}

/// The term names of `losses`: [`LOSS_TERMS`] (all of them, so each keeps its colour), then
/// any other name found, in name order.
fn term_names(losses: &[StepLosses]) -> Vec<&str> {
    let mut others: Vec<&str> = losses
        .iter()
        .flat_map(|l| l.terms.keys().map(String::as_str))
        .filter(|n| !LOSS_TERMS.contains(n))
        .collect();
    others.sort_unstable();
    others.dedup();
    LOSS_TERMS.iter().copied().chain(others).collect()
}

/// The series of term `name`: its value at every step that logs it.
fn term_series(losses: &[StepLosses], name: &str, color: [u8; 3]) -> Series {
    let points = losses
        .iter()
        .filter_map(|l| Some((l.step as f64, *l.terms.get(name)? as f64)))
        .collect();
    Series {
        name: name.into(),
        color,
        dashed: false,
        points,
    }
}

/// The smallest and largest of `values` (`(inf, -inf)` when there are none).
fn bounds(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    })
}

/// The stretches of consecutive points of `points` that `scale` shows.
fn runs(points: &[(f64, f64)], scale: YScale) -> Vec<Vec<(f64, f64)>> {
    points
        .split(|&p| !scale.shows(p))
        .filter(|run| !run.is_empty())
        .map(<[_]>::to_vec)
        .collect()
}

/// A tick value: plain with at most four decimals, or in exponent form when very
/// large or small.
fn tick_label(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        let text = format!("{v:.1e}");
        return text.replace(".0e", "e");
    }
    let text = format!("{v:.4}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" {
        "0".into()
    } else {
        text.into()
    }
}

/// Draws one row per entry of `legend` on `area`: a stroke of its colour and its name.
fn draw_legend(area: &Area, legend: &[(String, [u8; 3])]) -> Result<(), DrawError> {
    for (i, (name, color)) in legend.iter().enumerate() {
        let y = (LEGEND_TOP + i as u32 * LEGEND_ROW) as i32;
        let color = RGBColor(color[0], color[1], color[2]);
        area.draw(&PathElement::new([(6, y), (34, y)], color.stroke_width(3)))?;
        area.draw(&Text::new(name.as_str(), (42, y - 4), (FONT, TICK_SIZE)))?;
    }
    Ok(())
}

/// A strip `width x height` pixels (RGB, white) with `text` written in black in the charts'
/// font, cut at the strip's end: the label of a picture in a contact sheet.
pub fn label_strip(width: u32, height: u32, text: &str) -> Result<RgbImage, StylizeError> {
    register_font();
    let mut buf = vec![255u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        let font = (FONT, f64::from(height.saturating_sub(6).max(6))).into_font();
        root.draw(&Text::new(text.to_string(), (4, 2), font.color(&BLACK)))
            .and_then(|()| root.present())
            .map_err(|e| StylizeError::Plot(Box::new(e)))?;
    }
    Ok(RgbImage::from_raw(width, height, buf).expect("the buffer holds the strip"))
}

/// Registers the embedded Noto Sans as the charts' font, once.
fn register_font() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        let registered =
            plotters::style::register_font(FONT, FontStyle::Normal, notosans::REGULAR_TTF);
        assert!(registered.is_ok(), "the embedded Noto Sans is a valid font");
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_label_strip_holds_dark_text_at_its_left_only() {
        let strip = label_strip(200, 20, "3: cat.png x fire").unwrap();
        assert_eq!(strip.dimensions(), (200, 20));
        let dark = |x0: u32, x1: u32| {
            (x0..x1)
                .flat_map(|x| (0..20).map(move |y| (x, y)))
                .filter(|&(x, y)| strip.get_pixel(x, y).0[0] < 128)
                .count()
        };
        assert!(dark(0, 100) > 20, "the text is drawn");
        assert_eq!(dark(150, 200), 0, "and nothing past it");
    }

    /// The left edge of the legend column.
    const LEGEND_X: u32 = PLOT_WIDTH - LEGEND_WIDTH;

    /// A step with the total and the given terms.
    fn step(step: u64, total: f32, terms: &[(&str, f32)]) -> StepLosses {
        StepLosses {
            step,
            view: 0,
            total,
            terms: terms.iter().map(|&(n, v)| (n.to_string(), v)).collect(),
        }
    }

    /// 40 falling steps: directional and patch non-zero, content zero throughout, no
    /// background.
    fn falling_run() -> Vec<StepLosses> {
        (1..=40)
            .map(|i| {
                let d = 2.0 - 0.03 * i as f32;
                let p = 1.0 + 0.2 * (i as f32 * 0.7).sin();
                step(
                    i,
                    d + p,
                    &[("directional", d), ("patch", p), ("content", 0.0)],
                )
            })
            .collect()
    }

    /// The rows of the pixels of exactly `color` in columns `xs` of `img`.
    fn rows_of(img: &RgbImage, color: [u8; 3], xs: Range<u32>) -> Vec<u32> {
        xs.flat_map(|x| (0..img.height()).map(move |y| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0 == color)
            .map(|(_, y)| y)
            .collect()
    }

    /// The mean of `rows` (rows grow downwards).
    fn mean(rows: &[u32]) -> f64 {
        assert!(!rows.is_empty(), "no pixel of the colour there");
        rows.iter().map(|&y| y as f64).sum::<f64>() / rows.len() as f64
    }

    #[test]
    fn the_legend_lists_the_total_and_every_term_that_is_not_zero_throughout() {
        let legend = loss_chart(&falling_run()).legend();
        let expected = [
            ("total".to_string(), PALETTE[0]),
            ("directional".to_string(), PALETTE[1]),
            ("patch".to_string(), PALETTE[2]),
        ];
        assert_eq!(legend, expected);
        let with_other = [step(1, 1.0, &[("content", 0.5), ("zeta", 0.1)])];
        let names: Vec<String> = loss_chart(&with_other)
            .legend()
            .into_iter()
            .map(|e| e.0)
            .collect();
        assert_eq!(names, ["total", "content", "zeta"]);
    }

    #[test]
    fn every_curve_is_drawn_in_the_plot_and_the_legend_and_no_other() {
        let img = loss_chart(&falling_run()).render().unwrap();
        assert_eq!(img.dimensions(), (PLOT_WIDTH, PLOT_HEIGHT));
        let mut entry_rows = Vec::new();
        for (i, color) in PALETTE[..3].iter().enumerate() {
            assert!(rows_of(&img, *color, 0..LEGEND_X).len() > 100, "curve {i}");
            let legend_rows = rows_of(&img, *color, LEGEND_X..PLOT_WIDTH);
            assert!(legend_rows.len() >= 20, "legend entry {i}");
            let row = mean(&legend_rows);
            assert!(legend_rows.iter().all(|&y| (y as f64 - row).abs() <= 2.0));
            entry_rows.push(row);
        }
        for pair in entry_rows.windows(2) {
            assert!(
                (pair[1] - pair[0] - LEGEND_ROW as f64).abs() < 0.5,
                "{entry_rows:?}"
            );
        }
        for skipped in &PALETTE[3..] {
            assert!(rows_of(&img, *skipped, 0..PLOT_WIDTH).is_empty());
        }
    }

    /// The total lies on the patch term where the patch term is all of it: dashed and drawn
    /// over it, both stay visible.
    #[test]
    fn the_total_stays_visible_on_a_term_equal_to_it() {
        let equal: Vec<StepLosses> = (0..40u64)
            .map(|i| {
                let v = 2.0 - i as f32 / 40.0;
                step(i + 1, v, &[("patch", v)])
            })
            .collect();
        let img = loss_chart(&equal).render().unwrap();
        let total = rows_of(&img, PALETTE[0], 0..LEGEND_X).len();
        let patch = rows_of(&img, PALETTE[2], 0..LEGEND_X).len();
        assert!(
            total > 100 && patch > 100,
            "total {total}, patch {patch} pixels"
        );
    }

    #[test]
    fn a_falling_curve_is_higher_on_the_left_than_on_the_right() {
        let img = loss_chart(&falling_run()).render().unwrap();
        let third = LEGEND_X / 3;
        for color in [PALETTE[0], PALETTE[1]] {
            let left = mean(&rows_of(&img, color, 0..third));
            let right = mean(&rows_of(&img, color, 2 * third..LEGEND_X));
            assert!(left + 50.0 < right, "left row {left}, right row {right}");
        }
    }

    #[test]
    fn values_spanning_more_than_two_decades_go_on_a_log_axis() {
        let decaying: Vec<StepLosses> = (0..=40)
            .map(|i| step(i + 1, 10f32.powf(1.0 - i as f32 / 10.0), &[]))
            .collect();
        let chart = loss_chart(&decaying);
        assert_eq!(chart.y_scale(), YScale::Log);
        assert_eq!(loss_chart(&falling_run()).y_scale(), YScale::Linear);
        // On the log axis the exponential decay is a straight line: its middle step sits
        // halfway between its ends.
        let img = chart.render().unwrap();
        let row_at = |x: Range<u32>| mean(&rows_of(&img, PALETTE[0], x));
        let (x0, x1) = (
            img_column(&img, PALETTE[0], true),
            img_column(&img, PALETTE[0], false),
        );
        let mid = (x0 + x1) / 2;
        let (top, middle, bottom) = (
            row_at(x0..x0 + 3),
            row_at(mid - 1..mid + 2),
            row_at(x1 - 2..x1 + 1),
        );
        assert!(top + 200.0 < bottom, "{top} {bottom}");
        assert!(
            (middle - (top + bottom) / 2.0).abs() < 6.0,
            "{top} {middle} {bottom}"
        );
    }

    /// The first (`first`) or last column of `img` left of the legend holding `color`.
    fn img_column(img: &RgbImage, color: [u8; 3], first: bool) -> u32 {
        let mut xs = (0..LEGEND_X).filter(|&x| !rows_of(img, color, x..x + 1).is_empty());
        if first { xs.next() } else { xs.next_back() }.unwrap()
    }

    #[test]
    fn a_log_axis_skips_values_it_cannot_show_and_series_with_none() {
        let chart = Chart {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            series: vec![
                Series {
                    name: "wide".into(),
                    color: PALETTE[0],
                    points: vec![
                        (1.0, 1e3),
                        (2.0, 0.0),
                        (3.0, 1.0),
                        (4.0, f64::NAN),
                        (5.0, 1e-2),
                    ],
                    dashed: false,
                },
                Series {
                    name: "never positive".into(),
                    color: PALETTE[1],
                    points: vec![(1.0, 0.0), (2.0, -1.0)],
                    dashed: false,
                },
            ],
        };
        assert_eq!(chart.y_scale(), YScale::Log);
        assert_eq!(chart.legend(), [("wide".to_string(), PALETTE[0])]);
        assert_eq!(
            runs(&chart.series[0].points, YScale::Log),
            [vec![(1.0, 1e3)], vec![(3.0, 1.0)], vec![(5.0, 1e-2)]]
        );
        let range = chart.log_y_range();
        assert!((range.start / 1e-2 - 1.0).abs() < 0.01 && range.start < 1e-2);
        assert!((range.end / 1e3 - 1.0).abs() < 0.01 && range.end > 1e3);
        let img = chart.render().unwrap();
        assert!(!rows_of(&img, PALETTE[0], 0..LEGEND_X).is_empty());
        assert!(rows_of(&img, PALETTE[1], 0..PLOT_WIDTH).is_empty());
    }

    #[test]
    fn an_empty_log_a_single_step_and_nan_steps_still_draw() {
        let empty = loss_chart(&[]);
        assert!(empty.legend().is_empty());
        let img = empty.render().unwrap();
        assert!(PALETTE
            .iter()
            .all(|c| rows_of(&img, *c, 0..PLOT_WIDTH).is_empty()));

        let single = loss_chart(&[step(7, 2.5, &[("patch", 1.5)])]);
        assert_eq!(single.x_range(), 6.0..8.0);
        let img = single.render().unwrap();
        for color in [PALETTE[0], PALETTE[2]] {
            assert!(!rows_of(&img, color, 0..LEGEND_X).is_empty());
        }

        let nan = [step(1, 3.0, &[]), step(2, f32::NAN, &[]), step(3, 1.0, &[])];
        let chart = loss_chart(&nan);
        assert_eq!(chart.linear_y_range(), 0.9..3.1);
        assert!(!rows_of(&chart.render().unwrap(), PALETTE[0], 0..LEGEND_X).is_empty());
        let all_nan = loss_chart(&[step(1, f32::NAN, &[])]);
        assert!(all_nan.legend().is_empty());
        all_nan.render().unwrap();
    }

    #[test]
    fn tick_labels_are_short() {
        let cases = [
            (0.0, "0"),
            (-0.0, "0"),
            (2.0, "2"),
            (0.25, "0.25"),
            (1.0 / 3.0, "0.3333"),
            (1e-3, "0.001"),
            (1e-4, "1e-4"),
            (2.5e6, "2.5e6"),
            (-40.0, "-40"),
        ];
        for (v, text) in cases {
            assert_eq!(tick_label(v), text, "{v}");
        }
    }

    #[test]
    fn the_chart_is_written_as_a_png() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("losses.png");
        write_loss_plot(&path, &falling_run()).unwrap();
        let back = image::open(&path).unwrap().to_rgb8();
        assert_eq!(back, loss_chart(&falling_run()).render().unwrap());
    }
}
