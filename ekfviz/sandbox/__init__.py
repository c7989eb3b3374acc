"""A user's filter in a process of its own: :mod:`.host` is ekfviz's end of the channel,
:mod:`.child` the other (standard library and numpy only, any Python >= 3.8)."""
