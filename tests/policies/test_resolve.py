"""The one ``"package.module:attr"`` reader (rsb_maniskill/resolve.py, a root leaf; policies name their
factories with it first): what it returns, and one error per way a spec goes wrong."""
from __future__ import annotations

import collections
import math
import os

import pytest

from rsb_maniskill.resolve import resolve


def test_a_spec_names_a_module_attribute_dotted_or_not():
    assert resolve("os.path:join") is os.path.join
    assert resolve("collections:OrderedDict.fromkeys") == collections.OrderedDict.fromkeys
    assert resolve("math:pi", must_call=False) == math.pi


@pytest.mark.parametrize("spec, error, words", [
    ("os.path", ValueError, "'package.module:factory'"),
    (":join", ValueError, "both parts"),
    (None, ValueError, "both parts"),
    ("rsb_no_such_module_here:make", ImportError, "cannot import module 'rsb_no_such_module_here'"),
    ("os.path:no_such_function", AttributeError, "has no attribute 'no_such_function'"),
    ("math:pi", TypeError, "'pi' is not callable"),
])
def test_each_bad_spec_is_one_line_naming_what(spec, error, words):
    with pytest.raises(error) as err:
        resolve(spec, "backbone")
    message = str(err.value)
    assert message.startswith("backbone spec") and words in message and "\n" not in message
