"""The compiled parts: the kernel of small maps and JCBB's search, each kept because a
speed target needs it (``make bench``: "What each compiled extension buys"); everything
else is in pyproject.toml.

Every extension is optional: without a C compiler the install goes on, the filter uses
its numpy code throughout (``ekfviz.filters.ekf.HAVE_KERNEL`` is then False) and JCBB
searches in Python (``ekfviz.association.jcbb.HAVE_SEARCH`` False).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "ekfviz.filters._kernel",
            ["ekfviz/filters/_kernel.c"],
            extra_compile_args=["-O2", "-std=c99", "-Wall", "-Wextra", "-Wno-unused-parameter"],
            optional=True,
        ),
        Extension(
            "ekfviz.association._search",
            ["ekfviz/association/_search.c"],
            extra_compile_args=["-O2", "-std=c99", "-Wall", "-Wextra", "-Wno-unused-parameter"],
            optional=True,
        ),
    ]
)
