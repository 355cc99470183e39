//! A polar plot of a BRDF slice in the plane of incidence, painted with egui's
//! painter: the surface, the normal up, angle ticks every 15 degrees, the incident
//! direction (orange, left), the mirror direction (dashed), and the lobe r(theta_o).

use egui::{Color32, Pos2, Sense, Shape, Stroke, Ui, Vec2};
use meso_core::brdf::LobePoint;

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
const LOBE: Color32 = Color32::from_rgb(90, 170, 255);

/// Radii of the points (0..=1) for the chosen scale, and the value of the outer ring.
pub fn radii(lobe: &[LobePoint], scale: Scale) -> (Vec<f64>, f64) {
    let value = |p: &LobePoint| match scale {
        Scale::Foreshortened => p.value * p.theta_o_rad.cos(),
        _ => p.value,
    };
    let peak = lobe.iter().map(value).fold(0.0f64, f64::max);
    if peak <= 0.0 || !peak.is_finite() {
        return (vec![0.0; lobe.len()], 0.0);
    }
    let r = lobe
        .iter()
        .map(|p| match scale {
            Scale::Log => {
                let v = value(p) / peak;
                if v <= 1e-4 {
                    0.0
                } else {
                    1.0 + v.log10() / 4.0
                }
            }
            _ => value(p) / peak,
        })
        .collect();
    (r, peak)
}

/// Paints the plot into the available width and returns the outer ring's value.
pub fn show(ui: &mut Ui, lobe: &[LobePoint], theta_i_rad: f64, scale: Scale) -> f64 {
    let width = ui.available_width().max(120.0);
    let size = Vec2::new(width, width * 0.56);
    let (response, painter) = ui.allocate_painter(size, Sense::hover());
    let rect = response.rect;
    let origin = Pos2::new(rect.center().x, rect.bottom() - 0.06 * rect.height());
    let radius = (0.46 * rect.width()).min(0.88 * rect.height());
    let dir = |theta: f64| Vec2::new(theta.sin() as f32, -(theta.cos() as f32));
    let grid = Stroke::new(1.0, ui.visuals().weak_text_color().gamma_multiply(0.5));

    for quarter in 1..=4 {
        let r = radius * quarter as f32 / 4.0;
        let arc: Vec<Pos2> = (0..=90)
            .map(|k| origin + dir((k as f64 * 2.0 - 90.0).to_radians()) * r)
            .collect();
        painter.add(Shape::line(arc, grid));
    }
    for k in (-90..=90).step_by(15) {
        painter.line_segment(
            [origin, origin + dir((k as f64).to_radians()) * radius],
            grid,
        );
    }
    let surface = Stroke::new(2.0, ui.visuals().strong_text_color());
    painter.line_segment(
        [
            origin - Vec2::X * radius * 1.05,
            origin + Vec2::X * radius * 1.05,
        ],
        surface,
    );
    painter.arrow(
        origin + dir(-theta_i_rad) * radius,
        -dir(-theta_i_rad) * radius * 0.95,
        Stroke::new(2.0, INCIDENT),
    );
    let mirror = [origin, origin + dir(theta_i_rad) * radius];
    painter.add(Shape::dashed_line(
        &mirror,
        Stroke::new(1.0, grid.color),
        6.0,
        4.0,
    ));

    let (r, peak) = radii(lobe, scale);
    let curve: Vec<Pos2> = lobe
        .iter()
        .zip(&r)
        .map(|(p, r)| origin + dir(p.theta_o_rad) * (radius * *r as f32))
        .collect();
    painter.add(Shape::line(curve, Stroke::new(2.5, LOBE)));

    let label = match scale {
        Scale::Linear => format!("outer ring: f = {peak:.4e} 1/sr"),
        Scale::Foreshortened => format!("outer ring: f cos_o = {peak:.4e} 1/sr"),
        Scale::Log => format!("outer ring: f = {peak:.4e} 1/sr, rings: decades"),
    };
    painter.text(
        rect.left_top() + Vec2::new(4.0, 4.0),
        egui::Align2::LEFT_TOP,
        label,
        egui::FontId::proportional(13.0),
        ui.visuals().text_color(),
    );
    peak
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
}
