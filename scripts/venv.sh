# Sourced by run.sh and test.sh (from the repository's root). `ensure_venv SPEC [COVERS...]` makes .venv
# when it is missing and pip-installs SPEC (editable) only when the last install, recorded in
# .venv/installed.sha256 as the hash of pyproject.toml and the spec installed, was of neither SPEC nor
# one of the specs COVERS that include it (the test extras include the app), or pyproject.toml changed.
install_hash() {  # install_hash SPEC
    { cat pyproject.toml; printf '%s\n' "$1"; } | sha256sum | cut -d' ' -f1
}

ensure_venv() {
    local stamp=.venv/installed.sha256 spec
    if [ -x .venv/bin/python ] && [ -f "$stamp" ]; then
        for spec in "$@"; do
            [ "$(cat "$stamp")" = "$(install_hash "$spec")" ] && return 0
        done
    fi
    [ -x .venv/bin/python ] || python3 -m venv .venv
    rm -f "$stamp"
    .venv/bin/pip install -q --upgrade pip
    .venv/bin/pip install -q -e "$1"
    install_hash "$1" > "$stamp"
}
