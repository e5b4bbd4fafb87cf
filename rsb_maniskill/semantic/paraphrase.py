"""An episode's instruction in other words: every template of the instruction set it was drawn from.

Language-conditioned learners train on these so that they read the question and the candidate named
rather than one template's wording. The rewording never leaves the episode's set, so training on the
"seen" templates keeps the "unseen" (evaluation) wording held out.
"""
from __future__ import annotations

from rsb_maniskill.objects.family import get_family
from rsb_maniskill.semantic.spec import EpisodeSpec
from rsb_maniskill.semantic.suites import suite_source
from rsb_maniskill.semantic.templates import render_direct, render_instruction, sibling_template_ids


def paraphrases(spec: EpisodeSpec) -> tuple[str, ...]:
    """``spec.instruction`` first, then the same episode in every other template of its set.

    Raises ValueError when the templates do not reproduce ``spec.instruction`` (a spec written by
    another version of the templates): rewording it would train on instructions of another episode."""
    n, tid = spec.n_choices, spec.template_id
    family = get_family(spec.targets)
    lettered, direct = family.lettered(n), suite_source(spec.suite).direct
    ids = sibling_template_ids(n, tid, direct, lettered)
    texts = []
    for t in ids:
        if direct:  # a Direct instruction names its target
            texts.append(render_direct(n, t, spec.block_names[spec.target_block]))
        else:
            texts.append(render_instruction(n, t, spec.question, spec.options, spec.letters, spec.block_names,
                                            spec.block_of_option, lettered, family.noun))
    own = tid - ids.start
    if texts[own] != spec.instruction:
        raise ValueError(f"{spec.suite_id} seed {spec.seed}: template {tid} renders {texts[own]!r}, not the "
                         f"recorded {spec.instruction!r}")
    return (texts[own], *texts[:own], *texts[own + 1:])
