"""Numerical cores of the array-snapshot bearing trackers (Ryu, Lee & Lee 2001; Yang 1995 for PAST;
``docs/papers/array.md``): steering vectors, MUSIC, PAST, the angular innovation and its FLOPs."""
