"""Rich tables of a campaign's trials: one row per trial, the grid collapsed into one row."""

from __future__ import annotations

from rich.table import Table

from ilcpmac.campaign.plan import records_at
from ilcpmac.campaign.record import TrialRecord
from ilcpmac.signals.harmonics import RippleFigures


def _pct(figures: RippleFigures | None, name: str) -> str:
    return "-" if figures is None else f"{100 * getattr(figures, name):.3f}"


def _mnm(figures: RippleFigures | None, name: str) -> str:
    return "-" if figures is None else f"{1000 * getattr(figures, name):.2f}"


def _factor(factor: float | None) -> str:
    return "-" if factor is None else f"{factor:.0f}x"


def trials_table(records: list[TrialRecord], title: str = "ilcpmac run") -> Table:
    """The live table: per trial, measured and true ripple (% of mean torque) and what is left where."""
    table = Table(title=title, title_justify="left", header_style="bold")
    for name, justify in [("#", "right"), ("phase", "left"), ("set point", "left"),
                          ("pp meas %", "right"), ("rms meas %", "right"), ("pp true %", "right"),
                          ("rms true %", "right"), ("1x mN m", "right"), ("2x mN m", "right"),
                          ("cog mN m", "right"), ("rest mN m", "right"), ("noise %", "right"),
                          ("reduction", "right")]:
        table.add_column(name, justify=justify)
    grid = [r for r in records if r.role == "grid"]
    if grid:
        true_pp = [r.true.pp for r in grid if r.true is not None]
        span = f"true pp {100 * min(true_pp):.1f}..{100 * max(true_pp):.1f} %" if true_pp else ""
        table.add_row(f"1-{len(grid)}", "identify", f"multisine grid, {len(grid)} trials", *[""] * 3,
                      span, *[""] * 6)
    for r in records:
        if r.role == "grid":
            continue
        phase = r.phase + (" (baseline)" if r.role == "baseline" else "")
        m = r.measured
        table.add_row(str(r.index), phase, f"{r.torque_setpoint_nm:g} N m @ {r.speed_setpoint_hz:g} Hz",
                      _pct(m, "pp"), _pct(m, "rms"), _pct(r.true, "pp"), _pct(r.true, "rms"), _mnm(m, "amp_1x"),
                      _mnm(m, "amp_2x"), _mnm(m, "amp_cogging"), _mnm(m, "amp_rest"), _pct(m, "rest_rms"),
                      _factor(r.reduction_factor))
    return table


def summary_table(records: list[TrialRecord], setpoints: list[float]) -> Table:
    """Per ILC set point: uncompensated and final ripple, reduction factors, trials used."""
    table = Table(title="summary (ripple peak-to-peak, % of mean torque)", title_justify="left",
                  header_style="bold")
    for name in ("set point", "uncompensated meas", "final meas", "uncompensated true", "final true",
                 "reduction meas", "reduction true", "ILC trials"):
        table.add_column(name, justify="right")
    for torque in setpoints:
        base = records_at(records, torque, ("baseline",))
        done = records_at(records, torque, ("compensate", "ilc"))
        if not base or not done:
            continue
        b, f = base[0], done[-1]
        table.add_row(f"{torque:g} N m", _pct(b.measured, "pp"), _pct(f.measured, "pp"), _pct(b.true, "pp"),
                      _pct(f.true, "pp"), _factor(f.reduction_factor), _factor(f.reduction_factor_true),
                      str(sum(r.role == "ilc" for r in done)))
    return table
