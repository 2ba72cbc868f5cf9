"""Whether numpy's BLAS runs one thread, known for sure only when the variables that limit
it were set before numpy's import: the CLI sets them then (cli/__init__.py) and says so
here.  The fixed-width reader (files/tables.py) sums its digits by a matrix product when
this holds: with a BLAS thread pool, each of its small products wakes the pool, whose
threads then spin (~200 ms of CPU over the Xsens file's reading here), so it uses numpy's
own sums otherwise (the same numbers: exact integers either way).  numpy-free."""

#: True once the CLI has limited the BLAS to one thread before numpy's import
ONE_THREAD = False
