"""Markdown for certificates (one as a page, several as one table) and their file names."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from nehmo_core.verify.certify import Certificate


def certificate_stem(
    system: str, variant: str, distribution: str, tau: float, actuators: str = "ideal"
) -> str:
    """The file name (without suffix) of a certificate's JSON and Markdown (the actuator model
    named unless ideal)."""
    tail = "" if actuators == "ideal" else f"_{actuators}"
    return f"{system}_{variant.replace('+', '_')}_{distribution}_tau{tau:g}{tail}"


def _tracking(settings: dict[str, Any]) -> str:
    a = settings.get("actuator")
    if not a:
        return "ideal (q̇ = u)"
    return (
        f"{a['name']}: acceleration limits {a['accel']} rad/s², latency {a['latency']} s, "
        f"state noise {a['noise']} rad; each rollout starts reversing at full speed"
    )


def certificate_markdown(cert: Certificate) -> str:
    """One certificate: the claim, how it was earned, the search pool's bands."""
    s = cert.settings
    verdict = "certified" if cert.certified else "**not certified**"
    lines = [
        f"# Certificate: {cert.model}, τ = {cert.tau:g} s, {cert.distribution['name']} states",
        "",
        f"With confidence {cert.confidence:.4g}, a state drawn from the "
        f"{cert.distribution['name']} distribution with `V(τ, x) ≥ δ = {cert.delta:.4f}` m "
        "is driven into contact within τ by "
        f"some adversary of the set with probability at most **ε = {cert.epsilon:.4%}** "
        f"({cert.violations} violations in N = {cert.samples} fresh states; "
        f"target α = {s['alpha']}: {verdict}). {cert.accepted_share:.1%} of the distribution "
        "lies in that level set.",
        "",
        f"- distribution: {cert.distribution['what']}",
        f"- adversaries: {', '.join(s['adversaries'])}; rollout step {s['dt']} s; seed {s['seed']}",
        f"- the arm's tracking in the rollouts: {_tracking(s)}",
        f"- search: {cert.search['states']} states with V ≥ 0, {cert.search['violations_at_0']} "
        f"violations, δ found {cert.search['delta']:.4f} m",
        f"- wall time: {cert.wall_time_s:.0f} s",
        f"- command: `{cert.command}`",
        "",
        "| attempt δ [m] | violations | ε bound | in level set |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| {a['delta']:.4f} | {a['violations']} | {a['epsilon']:.4%} | {a['accepted_share']:.1%} |"
        for a in cert.attempts
    ]
    lines += ["", "Search pool by value band (descriptive, not certified):", ""]
    lines += ["| V band [m] | states | violations |", "|---|---|---|"]
    lines += [_band_row(b) for b in cert.search["bands"]]
    return "\n".join(lines) + "\n"


def _band_row(band: dict[str, Any]) -> str:
    lo, hi = band["band"]
    label = f"[{lo:g}, {hi:g})" if hi is not None else f"≥ {lo:g}"
    return f"| {label} | {band['states']} | {band['violations']} |"


def certificate_json_actuators(cert: dict[str, Any]) -> str:
    """The actuator model a certificate's JSON (``nehmo verify --out``) was made under."""
    return str((cert.get("settings", {}).get("actuator") or {}).get("name", "ideal"))


def certificates_table(certs: Sequence[dict[str, Any]]) -> str:
    """Several certificates (their JSON dicts) as one Markdown table."""
    lines = [
        "| model | τ [s] | distribution | actuators | δ [m] | N | violations | ε bound | certified "
        "| wall s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in certs:
        lines.append(
            f"| {c['model']} | {c['tau']:g} | {c['distribution']['name']} | "
            f"{certificate_json_actuators(c)} | {c['delta']:.3f} | "
            f"{c['samples']} | {c['violations']} | {c['epsilon']:.3%} | "
            f"{'yes' if c['certified'] else 'no'} | {c['wall_time_s']:.0f} |"
        )
    return "\n".join(lines) + "\n"
