"""libsumo, imported without the notice it prints at import.

The eclipse-sumo wheel's libsumo prints "pyarrow ... might be incompatible" whenever the installed pyarrow is
not the one it was built against; we never use its Arrow output, so the notice only confuses a user (up to six
times in `make demo`: once per worker process)."""

import contextlib
import io


def import_libsumo():
    with contextlib.redirect_stdout(io.StringIO()):
        import libsumo
    return libsumo
