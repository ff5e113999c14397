//! Writers for results: CSV, a self-contained HTML page (inline SVG drawn here, no
//! network, no fonts needed), PNG plots (plotters) and the datasheet-style comparison
//! table (rows: noise terms; columns: device × axis).
//!
//! The page opens with a summary (which IMU is better, by how much, and how long a GNSS
//! outage each bridges: [`outage`]) and ends with the data's health ([`health`]: gaps,
//! temperature and the daemon's events of every session input).
//!
//! One file per output: [`csv`], [`svg`] (the inline plot), [`png`], [`datasheet`] (the
//! noise-term table), [`summary`] and [`page`] (the HTML page), with [`text`] for how numbers
//! and units are printed.

mod csv;
mod datasheet;
pub mod health;
pub mod outage;
mod page;
mod png;
mod summary;
mod svg;
mod text;

pub use csv::write_csv;
pub use datasheet::{datasheet_table_html, datasheet_table_text};
pub use page::{
    html_report, html_report_with_sessions, html_report_with_study, plot_groups, with_section,
    PAGE_STYLE,
};
pub use png::{write_png, write_png_axes};
pub use summary::{summary_html, summary_html_with_study};
pub use svg::{
    svg_plot, term_lines, TermLine, LINE_STYLE_NOTE, SHORT_LINE_STYLE_NOTE, SVG_NAMESPACE,
};
pub use text::{deviation_unit, escape, pretty_unit, thermal_coefficient_text};
