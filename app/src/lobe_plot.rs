//! A polar plot of a BRDF slice in the plane of incidence, painted with egui's
//! painter: the surface, angle ticks every 15 degrees (labelled every 30), the light
//! direction (orange arrow, left), the mirror direction (dashed), the lobe r(theta_o),
//! a legend, and the value under the pointer. No axes library: it is one half-disk.

use egui::{Align2, Color32, FontId, Pos2, Rect, Sense, Shape, Stroke, Ui, Vec2};
use meso_materials::brdf::LobePoint;

/// How the radius encodes the value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Scale {
    /// r = f / max f.
    Linear,
    /// r = f cos_o / max: what a viewer sees, radiance-like.
    Foreshortened,
    /// Four decades of f on a log scale.
    Log,
}

const INCIDENT: Color32 = Color32::from_rgb(230, 120, 40);
const MIRROR: Color32 = Color32::from_gray(190);
const LOBE: Color32 = Color32::from_rgb(90, 170, 255);
/// Decades shown by the log scale: one ring per decade.
const LOG_DECADES: f64 = 4.0;

/// The plotted quantity at one point for the chosen scale.
fn plotted(p: &LobePoint, scale: Scale) -> f64 {
    match scale {
        Scale::Foreshortened => p.value * p.theta_o_rad.cos(),
        Scale::Linear | Scale::Log => p.value,
    }
}

/// Radii of the points (0..=1) for the chosen scale, and the value of the outer ring.
pub fn radii(lobe: &[LobePoint], scale: Scale) -> (Vec<f64>, f64) {
    let peak = lobe
        .iter()
        .map(|p| plotted(p, scale))
        .fold(0.0f64, f64::max);
    (radii_at(lobe, scale, peak), peak)
}

/// Radii of the points for an outer-ring value `peak` (shared by several curves).
fn radii_at(lobe: &[LobePoint], scale: Scale, peak: f64) -> Vec<f64> {
    if peak <= 0.0 || !peak.is_finite() {
        return vec![0.0; lobe.len()];
    }
    lobe.iter()
        .map(|p| {
            let v = plotted(p, scale) / peak;
            match scale {
                Scale::Log if v <= 10f64.powf(-LOG_DECADES) => 0.0,
                Scale::Log => 1.0 + v.log10() / LOG_DECADES,
                Scale::Linear | Scale::Foreshortened => v,
            }
        })
        .collect()
}

/// Numbers that stay short at any magnitude: four significant digits, scientific
/// notation outside [1e-3, 1e4).
pub fn format_value(x: f64) -> String {
    let a = x.abs();
    if a == 0.0 {
        "0".to_string()
    } else if (1e-3..1e4).contains(&a) {
        let decimals = (3 - a.log10().floor() as i32).clamp(0, 6) as usize;
        format!("{x:.decimals$}")
    } else {
        format!("{x:.3e}")
    }
}

/// What the plot says in numbers: where the lobe peaks and its value at the mirror.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Readout {
    pub peak_theta_o_rad: f64,
    pub peak_value: f64,
    /// f at the sample nearest the mirror direction theta_o = theta_i.
    pub mirror_value: f64,
}

pub fn readout(lobe: &[LobePoint], theta_i_rad: f64) -> Option<Readout> {
    let peak = lobe.iter().max_by(|a, b| a.value.total_cmp(&b.value))?;
    let mirror = lobe.iter().min_by(|a, b| {
        (a.theta_o_rad - theta_i_rad)
            .abs()
            .total_cmp(&(b.theta_o_rad - theta_i_rad).abs())
    })?;
    Some(Readout {
        peak_theta_o_rad: peak.theta_o_rad,
        peak_value: peak.value,
        mirror_value: mirror.value,
    })
}

/// Screen direction of a signed angle from the normal: 0 is up, positive to the right.
fn dir(theta_rad: f64) -> Vec2 {
    Vec2::new(theta_rad.sin() as f32, -(theta_rad.cos() as f32))
}

/// A further curve drawn on the same scale as the lobe (e.g. one basis of a sum).
pub struct Extra<'a> {
    pub points: &'a [LobePoint],
    pub color: Color32,
}

/// Paints the plot into the available width (and at most `max_height`) and returns
/// the outer ring's value. `extra` curves share the lobe's scale.
pub fn show(
    ui: &mut Ui,
    lobe: &[LobePoint],
    extra: &[Extra<'_>],
    theta_i_rad: f64,
    scale: Scale,
    max_height: f32,
) -> f64 {
    let width = ui.available_width().max(160.0);
    let height = (width * 0.62).min(max_height).max(120.0);
    let (response, painter) = ui.allocate_painter(Vec2::new(width, height), Sense::hover());
    let rect = response.rect;
    let font = FontId::proportional(12.0);
    let text_color = ui.visuals().text_color();
    let weak = ui.visuals().weak_text_color();

    // Room above the rim for the header and the angle labels, beside it for +-90.
    let header_h = 22.0;
    let label_gap = 16.0;
    let radius = (0.5 * rect.width() - 2.0 * label_gap)
        .min(rect.height() - header_h - label_gap - 10.0)
        .max(20.0);
    let origin = Pos2::new(rect.center().x, rect.bottom() - 10.0);
    let at = |theta: f64, r: f32| origin + dir(theta) * r;

    let grid = Stroke::new(1.0, weak.gamma_multiply(0.5));
    for quarter in 1..=4 {
        let r = radius * quarter as f32 / 4.0;
        let arc: Vec<Pos2> = (0..=90)
            .map(|k| at((k as f64 * 2.0 - 90.0).to_radians(), r))
            .collect();
        painter.add(Shape::line(arc, grid));
    }
    for k in (-90i32..=90).step_by(15) {
        let theta = (k as f64).to_radians();
        painter.line_segment([origin, at(theta, radius)], grid);
        if k % 30 == 0 {
            // +-90 sit on the surface line: lift them above it.
            let pos = if k.abs() == 90 {
                at(theta, radius + label_gap) - Vec2::Y * 8.0
            } else {
                at(theta, radius + label_gap * 0.75)
            };
            painter.text(
                pos,
                Align2::CENTER_CENTER,
                format!("{}°", k.abs()),
                font.clone(),
                weak,
            );
        }
    }
    let surface = Stroke::new(2.0, ui.visuals().strong_text_color());
    painter.line_segment(
        [
            origin - Vec2::X * (radius + 4.0),
            origin + Vec2::X * (radius + 4.0),
        ],
        surface,
    );
    // The light arrives along -wi: an arrow from the rim on the incident side to the
    // surface point, with a head of fixed size (egui's arrow scales it with length).
    let incident = Stroke::new(2.0, INCIDENT);
    let tail = at(-theta_i_rad, radius);
    painter.line_segment([tail, origin], incident);
    let back = dir(-theta_i_rad) * 15.0;
    for side in [-0.5f32, 0.5] {
        painter.line_segment(
            [origin, origin + egui::emath::Rot2::from_angle(side) * back],
            incident,
        );
    }
    painter.extend(Shape::dashed_line(
        &[origin, at(theta_i_rad, radius)],
        Stroke::new(1.5, MIRROR),
        6.0,
        4.0,
    ));

    let (r, peak) = radii(lobe, scale);
    for e in extra {
        let curve: Vec<Pos2> = e
            .points
            .iter()
            .zip(radii_at(e.points, scale, peak))
            .map(|(p, r)| at(p.theta_o_rad, radius * r as f32))
            .collect();
        painter.add(Shape::line(curve, Stroke::new(1.5, e.color)));
    }
    let curve: Vec<Pos2> = lobe
        .iter()
        .zip(&r)
        .map(|(p, r)| at(p.theta_o_rad, radius * *r as f32))
        .collect();
    painter.add(Shape::line(curve, Stroke::new(2.5, LOBE)));

    let header = match scale {
        Scale::Linear => format!(
            "outer ring f = {} 1/sr, rings at quarters",
            format_value(peak)
        ),
        Scale::Foreshortened => format!(
            "outer ring f cos θo = {} 1/sr, rings at quarters",
            format_value(peak)
        ),
        Scale::Log => format!(
            "outer ring f = {} 1/sr, one ring per decade",
            format_value(peak)
        ),
    };
    painter.text(
        rect.left_top() + Vec2::new(2.0, 2.0),
        Align2::LEFT_TOP,
        header,
        font.clone(),
        text_color,
    );
    legend(&painter, rect, &font, text_color);

    if let Some(text) = response
        .hover_pos()
        .and_then(|pointer| hover_text(pointer - origin, lobe, scale))
    {
        response.on_hover_text_at_pointer(text);
    }
    peak
}

/// Swatches for the three curves, in the top-right corner outside the half-disk.
fn legend(painter: &egui::Painter, rect: Rect, font: &FontId, color: Color32) {
    let entries = [
        ("light", Stroke::new(2.0, INCIDENT), false),
        ("mirror", Stroke::new(1.5, MIRROR), true),
        ("lobe", Stroke::new(2.5, LOBE), false),
    ];
    for (k, (name, stroke, dashed)) in entries.into_iter().enumerate() {
        let y = rect.top() + 28.0 + 16.0 * k as f32;
        let right = rect.right() - 4.0;
        let text_rect = painter.text(
            Pos2::new(right, y),
            Align2::RIGHT_CENTER,
            name,
            font.clone(),
            color,
        );
        let a = Pos2::new(text_rect.left() - 26.0, y);
        let b = Pos2::new(text_rect.left() - 6.0, y);
        if dashed {
            painter.extend(Shape::dashed_line(&[a, b], stroke, 5.0, 3.0));
        } else {
            painter.line_segment([a, b], stroke);
        }
    }
}

/// Tooltip text with theta_o and f for the direction of `offset` from the origin;
/// None below the surface.
fn hover_text(offset: Vec2, lobe: &[LobePoint], scale: Scale) -> Option<String> {
    if offset.y > 0.0 || offset.length() < 1.0 {
        return None;
    }
    let theta = f64::from(offset.x).atan2(f64::from(-offset.y));
    let p = lobe.iter().min_by(|a, b| {
        (a.theta_o_rad - theta)
            .abs()
            .total_cmp(&(b.theta_o_rad - theta).abs())
    })?;
    let mut text = format!(
        "θo = {:.1}°\nf = {} 1/sr",
        p.theta_o_rad.to_degrees(),
        format_value(p.value)
    );
    if scale == Scale::Foreshortened {
        text += &format!("\nf cos θo = {} 1/sr", format_value(plotted(p, scale)));
    }
    Some(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lobe() -> Vec<LobePoint> {
        (0..5)
            .map(|k| LobePoint {
                theta_o_rad: (k as f64 - 2.0) * 0.5,
                value: 1.0 + k as f64,
            })
            .collect()
    }

    #[test]
    fn linear_radii_are_relative_to_the_peak() {
        let (r, peak) = radii(&lobe(), Scale::Linear);
        assert_eq!(peak, 5.0);
        assert_eq!(r, vec![0.2, 0.4, 0.6, 0.8, 1.0]);
    }

    #[test]
    fn foreshortened_radii_weight_by_cos_theta_o() {
        let l = vec![
            LobePoint {
                theta_o_rad: 0.0,
                value: 1.0,
            },
            LobePoint {
                theta_o_rad: 60f64.to_radians(),
                value: 1.0,
            },
        ];
        let (r, peak) = radii(&l, Scale::Foreshortened);
        assert_eq!(peak, 1.0);
        assert!((r[1] - 0.5).abs() < 1e-12, "{r:?}");
    }

    #[test]
    fn log_radii_span_four_decades() {
        let l = vec![
            LobePoint {
                theta_o_rad: 0.0,
                value: 1.0,
            },
            LobePoint {
                theta_o_rad: 0.1,
                value: 1e-2,
            },
            LobePoint {
                theta_o_rad: 0.2,
                value: 1e-5,
            },
        ];
        let (r, _) = radii(&l, Scale::Log);
        assert!(
            (r[0] - 1.0).abs() < 1e-12 && (r[1] - 0.5).abs() < 1e-12 && r[2] == 0.0,
            "{r:?}"
        );
    }

    #[test]
    fn an_all_zero_lobe_has_zero_radii() {
        let l = vec![LobePoint {
            theta_o_rad: 0.0,
            value: 0.0,
        }];
        assert_eq!(radii(&l, Scale::Foreshortened), (vec![0.0], 0.0));
    }

    #[test]
    fn readout_finds_peak_and_mirror() {
        let r = readout(&lobe(), 0.4).expect("non-empty");
        assert_eq!(r.peak_theta_o_rad, 1.0);
        assert_eq!(r.peak_value, 5.0);
        // Samples at -1, -0.5, 0, 0.5, 1: nearest to 0.4 is 0.5, value 4.
        assert_eq!(r.mirror_value, 4.0);
        assert_eq!(readout(&[], 0.0), None);
    }

    #[test]
    fn hover_reads_the_nearest_sample() {
        // Straight up is theta_o = 0, the middle sample (value 3).
        let text = hover_text(Vec2::new(0.0, -50.0), &lobe(), Scale::Linear).expect("above");
        assert_eq!(text, "θo = 0.0°\nf = 3.000 1/sr");
        // 30 degrees to the right of the normal: nearest sample 0.5 rad (value 4).
        let up_right = Vec2::new(25.0, -43.3);
        let text = hover_text(up_right, &lobe(), Scale::Linear).expect("above");
        assert!(
            text.contains("28.6°") && text.contains("f = 4.000"),
            "{text}"
        );
        assert_eq!(
            hover_text(Vec2::new(0.0, 5.0), &lobe(), Scale::Linear),
            None
        );
    }

    #[test]
    fn values_are_formatted_short() {
        assert_eq!(format_value(0.0), "0");
        assert_eq!(format_value(2.84423), "2.844");
        assert_eq!(format_value(0.012345), "0.01235");
        assert_eq!(format_value(123.456), "123.5");
        assert_eq!(format_value(12345.0), "1.234e4");
        assert_eq!(format_value(2.5e-5), "2.500e-5");
    }
}
