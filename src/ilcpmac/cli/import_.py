"""``ilcpmac import``: drive logs (rows at a fixed rate) into a bench folder (one row per encoder count), a scan
folder or a rolling folder (rows as they are)."""

from __future__ import annotations

from pathlib import Path

import click

from ilcpmac.cli import console, main


@main.command("import")
@click.argument("logs", nargs=-1, required=True, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--map", "mapping_file", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Mapping file: the logs' columns, units and scales, the motor (docs/bench-format.md).")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Bench folder to write (must not hold a bench.toml yet).")
@click.option("--format", "trial_format", type=click.Choice(["csv", "parquet"]), default="csv", show_default=True,
              help="File format of the trials.")
def import_(logs: tuple[Path, ...], mapping_file: Path, out_dir: Path, trial_format: str) -> None:
    """Turn drive LOGS into a bench folder.

    Each log (rows at a fixed rate) is cut into laps where its position turns and each lap resampled onto
    encoder counts, one trial per lap; prints each trial written with its set point and the estimated
    interpolation error (docs/bench-format.md). Reverse laps are mirrored into a second bench folder,
    OUT_DIR-reverse ([motor] mirrored = true). Logs without a torque column make a bench without a torque
    sensor. Logs of a standstill scan ([log] kind = "scan"), or moteus cogging files ([log] kind =
    "moteus-cogging"), become one scan folder (docs/standstill.md). Rolling logs ([log] kind = "rolling"), and
    run logs that cannot be resampled per count (a position that stick-slips or dithers, less than whole
    revolutions, rows too sparse for the counts, a gap), are kept row by row as a rolling folder, their steady part
    (docs/rolling-logs.md); the command says which and why.
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from rich.markup import escape

    from ilcpmac.bench.holding_map import HoldingMapMapping, import_holding_maps, import_lines
    from ilcpmac.bench.importer import NotPerCount, import_logs, read_mapping, write_scan_folder
    from ilcpmac.bench.moteus import MoteusMapping, q_torque_constant

    mapping = read_mapping(mapping_file)
    if isinstance(mapping, HoldingMapMapping):  # a drive's own maps (docs/drive-maps.md)
        for line in import_lines(import_holding_maps(list(logs), mapping, out_dir), out_dir):
            console.print(escape(line))
        return
    if not isinstance(mapping, MoteusMapping) and mapping.layout.kind == "rolling":
        _write_rolling(list(logs), mapping, out_dir)
        return
    if isinstance(mapping, MoteusMapping) or mapping.layout.kind == "scan":
        scan = write_scan_folder(list(logs), mapping, out_dir)
        forward = int((scan.direction > 0).sum())
        moteus = isinstance(mapping, MoteusMapping)
        console.print(f"{len(logs)} {'moteus cogging files' if moteus else 'scan logs'} -> scan.csv: {forward} "
                      f"forward and {scan.direction.size - forward} reverse samples, holding "
                      f"{'torque' if scan.torque_nm is not None else 'currents'}")
        if isinstance(mapping, MoteusMapping):
            k_q = q_torque_constant(mapping.backemf_nm_per_a, mapping.motor.pole_pairs)
            console.print(f"holding torque = k_q i_q, k_q = {k_q:.4g} N m / A (3/2 of the back-EMF's fundamental)")
        console.print(f"wrote scan.csv, scan.toml, backemf.csv and bench.toml to {out_dir}")
        return
    harmonic = mapping.layout.highest_harmonic
    try:
        benches = import_logs(list(logs), mapping, out_dir, f".{trial_format}")
    except NotPerCount as refusal:
        _write_rolling(list(logs), mapping, out_dir, "kept as a rolling log, its rows as they are (as \\[log] kind = "
                       f"\"rolling\"; docs/rolling-logs.md), not resampled per count: {escape(str(refusal))}")
        return
    for imported in benches:
        mirrored = imported.bench.motor.mirrored
        for name, r in zip(imported.bench.trial_files, imported.laps):
            t, e = r.trial, r.error
            lap = "" if r.lines is None else f" lines {r.lines[0]}-{r.lines[1]}"
            target = f"{imported.folder.name}/{name}" if mirrored else name
            torque = (f", {e.torque_nm:.2g} N m" if e.torque_nm is not None else
                      f"; no torque: encoder torque at harmonic {harmonic} {100 * r.torque_loss:.2g} % low")
            console.print(f"{escape(str(r.log))}{lap}{' (reverse, mirrored)' if mirrored else ''} -> "
                          f"{escape(target)}: {t.n_samples} counts, {t.torque_setpoint_nm:g} N m at "
                          f"{t.speed_setpoint_hz:g} Hz, harmonics up to {r.resolved_harmonic} resolved; interpolation "
                          f"error <= {e.time_s:.2g} s, {e.current_a:.2g} A{torque}")
        motor = imported.bench.motor
        if not motor.torque_sensor:
            console.print(f"no torque column: \\[motor] torque_sensor = false, timer_resolution_s = "
                          f"{motor.timer_resolution_s:.3g} (identified on the encoder's time stamps)")
        note = (" - reverse laps as forward laps of the motor's mirror image (\\[motor] mirrored = true, "
                "backemf.csv mirrored)" if mirrored else "")
        console.print(f"wrote {len(imported.laps)} trials, backemf.csv and bench.toml to "
                      f"{escape(str(imported.folder))}{note}")


def _write_rolling(logs: list[Path], mapping, out_dir: Path, why: str | None = None) -> None:
    """Write ``logs`` as the rolling folder ``out_dir`` and say why (``why``, once it is written: a refusal stays
    the command's one line) and what each kept."""
    from rich.markup import escape

    from ilcpmac.bench.importer import write_rolling_folder

    kept_logs = write_rolling_folder(logs, mapping, out_dir)
    if why is not None:
        console.print(why)
    for kept in kept_logs:
        console.print(f"{escape(str(kept.log))} -> segment: {escape(kept.text())}")
    console.print(f"wrote rolling.csv, rolling.toml, backemf.csv and bench.toml to {escape(str(out_dir))}")
