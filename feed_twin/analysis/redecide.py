"""Each found effect decided again with every later one in the model: a backward-forward step.

The rounds add one effect at a time, each chosen on the residual of the model before it: a
drive gain (torque_constant_error) scales the nominal Coulomb force too, so before a grown
Coulomb force is in the model it explains more of a heavier table than the table's own mass
does, and once both are in, nothing looks at that choice again (the truth machine's weight +
Coulomb + mass: the gain named, the mass not, weight and Coulomb 24 % and 28 % off). So once
the rounds end, each found effect (fitted by least squares, beside at least one other) is
removed, the others are fitted again without it (analysis.reexamine.without), and one round
of analysis.rounds runs on that model, the removed effect among its candidates on equal
terms: the round keeps whichever passes and ranks best (it may be the same effect), in the
removed one's place. If the round keeps nothing, the effect and its model are put back.
"""

from __future__ import annotations

from feed_twin.analysis.channels import weighted_channels
from feed_twin.analysis.rounds import Context, State, found_without, run_round


def redecide(state: State, ctx: Context, excluded: list[str], unfitted: list[dict]) -> None:
    """The backward-forward step (module docstring) for each found effect in turn."""
    for target in list(state.found):
        if target not in state.found or not target.own or len(state.found) < 2:
            continue
        at = state.found.index(target)
        meas = weighted_channels(ctx.run, state.outputs, ctx.stride, ctx.floors, start=ctx.start)
        gone = found_without(target, state, ctx, meas)
        if gone is None:
            continue
        saved = (list(state.found), state.doc, state.twin, state.outputs, state.cost)
        state.simulations += gone.simulations
        state.found.remove(target)
        state.doc, state.twin, state.outputs = gone.doc, gone.twin, gone.outputs
        ctx.tried.clear()
        names = {f.name for f in state.found}
        open_ = [n for n in excluded if n not in names and n != target.name]
        ctx.progress(f"deciding {target.name} again with the other effects in the model")
        run_round(0, state, ctx, open_ + sorted(names), unfitted)
        added = [f for f in state.found if f not in saved[0]]
        if not added:
            state.found, state.doc, state.twin, state.outputs, state.cost = saved
            continue
        state.found.remove(added[0])
        state.found.insert(min(at, len(state.found)), added[0])
        if added[0].name != target.name:
            ctx.notes.append(
                f"{target.name} was replaced by {added[0].name} once the effects found after "
                "it were in the model (decided again on their residual)"
            )
