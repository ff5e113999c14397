//! Report plots: every identified noise term gets its own labelled asymptote next to the
//! fitted total and the confidence band, in the HTML (SVG) and in the PNG.

use imulab::allan::analysis::{analyse_axis, AllanReport, AnalysisOptions};
use imulab::allan::fit::Term;
use imulab::allan::input::AxisSeries;
use imulab::allan::units::RateUnit;
use imulab::allan::{DeviationKind, TauGrid};
use imulab::report::{html_report, svg_plot, term_lines, write_png};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::Xoshiro256PlusPlus;

/// White rate noise N = 2e-3 and rate random walk K = 5e-4 at 100 Hz.
fn analysed_gyro_axis() -> imulab::allan::analysis::AxisResult {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(21);
    let mut walk = 0.0;
    let rate: Vec<f64> = (0..400_000)
        .map(|_| {
            let white: f64 = StandardNormal.sample(&mut rng);
            let step: f64 = StandardNormal.sample(&mut rng);
            walk += 5e-4 * 0.1 * step;
            2e-3 * 10.0 * white + walk
        })
        .collect();
    let series = AxisSeries::one_segment("gyro_x", 0.01, rate);
    let options = AnalysisOptions {
        kind: DeviationKind::Oadev,
        grid: TauGrid::Octave,
        fit: true,
        unit: RateUnit::RadPerSecond,
        sensor: RateUnit::RadPerSecond.sensor(),
    };
    analyse_axis("imu0", series, &options)
}

#[test]
fn each_identified_term_has_its_own_labelled_line() {
    let axis = analysed_gyro_axis();
    let fit = axis.fit.as_ref().expect("fit");
    let identified: Vec<Term> = fit
        .terms
        .iter()
        .filter(|t| t.value.is_some())
        .map(|t| t.term)
        .collect();
    assert!(identified.contains(&Term::RandomWalk) && identified.contains(&Term::RateRandomWalk));
    let (lo, hi) = (
        axis.curve.points[0].tau,
        axis.curve.points.last().unwrap().tau,
    );
    let lines = term_lines(fit, lo, hi);
    assert_eq!(
        lines.iter().map(|l| l.term).collect::<Vec<_>>(),
        identified,
        "one line per identified term, none for the others"
    );
    for line in &lines {
        // Each line is the term alone: below the total everywhere, close to it where the
        // label sits (the term dominates there).
        let total = fit.model_deviation(line.label_at.0);
        assert!(line.label_at.1 <= total * (1.0 + 1e-12));
        assert!(line.label_at.1 >= 0.7 * total, "{line:?} total {total}");
        assert_eq!(line.from.0, lo);
        assert_eq!(line.to.0, hi);
    }
    let n = lines.iter().find(|l| l.term == Term::RandomWalk).unwrap();
    let k = lines
        .iter()
        .find(|l| l.term == Term::RateRandomWalk)
        .unwrap();
    // Slopes −1/2 and +1/2 on log-log axes; N dominates short τ, K long τ.
    let slope = |l: &imulab::report::TermLine| (l.to.1 / l.from.1).ln() / (hi / lo).ln();
    assert!((slope(n) + 0.5).abs() < 1e-12 && (slope(k) - 0.5).abs() < 1e-12);
    assert!(n.label_at.0 < k.label_at.0);

    let svg = svg_plot(&[&axis], "imu0 gyro");
    for term in &identified {
        assert!(
            svg.contains(&format!(">{}</text>", term.symbol())),
            "label {} missing",
            term.symbol()
        );
    }
    assert!(
        svg.contains("clip-path=\"url(#plot-"),
        "term lines are clipped"
    );
    assert!(
        svg.contains("stroke-dasharray=\"5,4\""),
        "fitted total drawn"
    );
    assert!(svg.contains("<polygon"), "confidence band drawn");
    assert!(
        svg.contains("dotted: fitted terms"),
        "line styles explained"
    );
}

#[test]
fn html_and_png_carry_the_term_lines() {
    let axis = analysed_gyro_axis();
    let report = AllanReport::new(
        vec!["sim".into()],
        DeviationKind::Oadev,
        "octave",
        vec![axis],
    );
    let html = html_report(&report, "plot test");
    assert!(html.contains(">N</text>") && html.contains(">K</text>"));
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("curves.png");
    write_png(&report, &png).expect("png");
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    assert!(bytes.len() > 10_000, "a real plot, {} bytes", bytes.len());
}
