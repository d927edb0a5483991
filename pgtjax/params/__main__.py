"""``python3 -m pgtjax.params``: print the parameter reference (the text of ``docs/parameters.md``)."""

from ._schema import reference_document

print(reference_document(), end="")
