"""The ``loggrasp`` command. Sub-commands are thin wrappers over library functions; every heavy
import happens inside a command so that ``loggrasp --help`` is instant."""

from __future__ import annotations

import typer

from planner.cli import eval_command, plan_command, train_command
from reconstruct.cli import scan_command
from synth.cli import app as synth_app

app = typer.Typer(
    help="loggrasp — multi-log grasp planning for forestry cranes, from simulator twin to field.",
    no_args_is_help=True, pretty_exceptions_enable=False,
)
synth_app.command("scan")(scan_command)
app.add_typer(synth_app, name="synth")
app.command("train")(train_command)
app.command("plan")(plan_command)
app.command("eval")(eval_command)


@app.command("demo")
def demo(
    out: str = typer.Option("out/demo", "--out", help="Output folder."),
    seed: int = typer.Option(7, "--seed", help="Seed of the demo pile."),
) -> None:
    """The main job on the embedded default: generate a pile, render it, write pictures."""
    from pathlib import Path

    from synth.generate import GenerationConfig, generate_pile
    from synth.pile import write_pile
    from synth.preview import preview_image, write_png
    from synth.render import OrthoRenderConfig, render_ortho
    from synth.world import World

    out_dir = Path(out)
    pile, report = generate_pile(seed, GenerationConfig(n_logs=5, n_obstacles=2))
    write_pile(pile, out_dir / "pile.json")
    with World(pile) as world:
        obs = render_ortho(world, OrthoRenderConfig(), seed=seed)
    obs.save(out_dir / "ortho.npz")
    write_png(out_dir / "preview.png", preview_image(obs))
    typer.echo(f"pile of {pile.n_logs} logs, {pile.n_obstacles} obstacles settled in {report.settle_time_s:.2f} s sim")
    typer.echo(f"wrote {out_dir}/pile.json, ortho.npz, preview.png")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
