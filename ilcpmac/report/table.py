"""Rich tables of a campaign's trials: one row per trial, the grid collapsed into one row."""

from __future__ import annotations

from rich.table import Table


def _pct(record: dict, key: str) -> str:
    return f"{100 * record[key]:.3f}" if key in record else "-"


def _mnm(record: dict, key: str) -> str:
    return f"{1000 * record[key]:.2f}" if key in record else "-"


def trials_table(records: list[dict], title: str = "ilcpmac run") -> Table:
    """The live table: per trial, measured and true ripple (% of mean torque) and what is left where."""
    table = Table(title=title, title_justify="left", header_style="bold")
    for name, justify in [("#", "right"), ("phase", "left"), ("set point", "left"),
                          ("pp meas %", "right"), ("rms meas %", "right"), ("pp true %", "right"),
                          ("rms true %", "right"), ("1x mN m", "right"), ("2x mN m", "right"),
                          ("cog mN m", "right"), ("rest mN m", "right"), ("noise %", "right"),
                          ("reduction", "right")]:
        table.add_column(name, justify=justify)
    grid = [r for r in records if r["role"] == "grid"]
    if grid:
        true_pp = [r["ripple_pp_true"] for r in grid if "ripple_pp_true" in r]
        span = f"true pp {100 * min(true_pp):.1f}..{100 * max(true_pp):.1f} %" if true_pp else ""
        table.add_row(f"1-{len(grid)}", "identify", f"multisine grid, {len(grid)} trials", *[""] * 3,
                      span, *[""] * 6)
    for r in records:
        if r["role"] == "grid":
            continue
        reduction = f"{r['reduction_factor']:.0f}x" if "reduction_factor" in r else "-"
        phase = r["phase"] + (" (baseline)" if r["role"] == "baseline" else "")
        table.add_row(str(r["index"]), phase, f"{r['torque_setpoint']:g} N m @ {r['speed_setpoint']:g} Hz",
                      _pct(r, "ripple_pp_measured"), _pct(r, "ripple_rms_measured"), _pct(r, "ripple_pp_true"),
                      _pct(r, "ripple_rms_true"), _mnm(r, "amp_1x_measured_nm"), _mnm(r, "amp_2x_measured_nm"),
                      _mnm(r, "amp_cogging_measured_nm"), _mnm(r, "amp_rest_measured_nm"),
                      _pct(r, "rest_rms_measured"), reduction)
    return table


def summary_table(summary: dict, setpoints: list[float]) -> Table:
    """Per ILC set point: uncompensated and final ripple, reduction factors, trials used."""
    table = Table(title="summary (ripple peak-to-peak, % of mean torque)", title_justify="left",
                  header_style="bold")
    for name in ("set point", "uncompensated meas", "final meas", "uncompensated true", "final true",
                 "reduction meas", "reduction true", "ILC trials"):
        table.add_column(name, justify="right")
    records = summary["trials"]
    for torque in setpoints:
        base = [r for r in records if r["role"] == "baseline" and r["torque_setpoint"] == torque]
        done = [r for r in records if r["role"] in ("compensate", "ilc") and r["torque_setpoint"] == torque]
        if not base or not done:
            continue
        b, f = base[0], done[-1]
        table.add_row(f"{torque:g} N m", _pct(b, "ripple_pp_measured"), _pct(f, "ripple_pp_measured"),
                      _pct(b, "ripple_pp_true"), _pct(f, "ripple_pp_true"),
                      f"{f.get('reduction_factor', float('nan')):.0f}x",
                      f"{f['reduction_factor_true']:.0f}x" if "reduction_factor_true" in f else "-",
                      str(sum(r["role"] == "ilc" for r in done)))
    return table
