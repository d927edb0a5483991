"""Model builders: pure functions from parameters to a :class:`pgtjax.System` (or to matrices that a
system is assembled from). One module per model of the documents."""
