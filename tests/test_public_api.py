"""The public API of ``import hyperoc``: the lazily imported names (`hyperoc._LAZY`) are those of
``__all__``, each is defined where `_LAZY` says it is found, and the API reference documents each."""

import re
from pathlib import Path

import pytest

import hyperoc

API_PAGE = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def test_lazy_names_and_all_list_the_same_names_once():
    assert len(hyperoc.__all__) == len(set(hyperoc.__all__))
    assert set(hyperoc._LAZY) == set(hyperoc.__all__)
    assert set(hyperoc.__all__) <= set(dir(hyperoc))


@pytest.mark.parametrize("name", sorted(hyperoc.__all__))
def test_every_public_name_resolves_and_is_documented(name):
    """``hyperoc.<name>`` is the object of its submodule, and docs/api.md has a ``:::`` entry for it, at the
    submodule of `_LAZY` or where the object is defined."""
    module = f"hyperoc.{hyperoc._LAZY[name]}"
    value = getattr(hyperoc, name)
    assert value is getattr(__import__(module, fromlist=[name]), name)
    documented = set(re.findall(r"^::: (hyperoc\.[\w.]+)", API_PAGE.read_text(), re.M))
    assert {f"{module}.{name}", f"{getattr(value, '__module__', module)}.{name}"} & documented


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'optimise'"):
        hyperoc.optimise  # noqa: B018
