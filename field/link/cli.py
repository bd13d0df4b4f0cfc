"""``loggrasp link-key`` and the key checks of every command that opens a crane link (``trial``,
``crane-sim``, ``replay --link``): authenticated by default, the opt-out explicit.

Thin over :mod:`field.link.secoc` (the pre-shared SecOC key) and :mod:`field.link.signing` (the
crane's Ed25519 signing key pair); every key file a link URL names is loaded before any work, so
a wrong one is a one-line error naming the file and its URL parameter (exit 2).
"""

from __future__ import annotations

from pathlib import Path

import typer

from synth.common.cli import EXIT_LINK, CliError, Output, check_output_file, option

INSECURE_LINK = option("--insecure-link", "Run the crane link WITHOUT a SecOC key (frames not authenticated: any "
                       "node on the bus could forge commands and answers), or with a key but without the crane's "
                       "signature keys (a laptop's key file could forge the crane's answers); the explicit opt-out, "
                       "said in the confirmation and the record. Without it a link needs ?secoc_key=KEYFILE and "
                       "crane_key=CRANE.pub (laptop) / signing_key=CRANE (crane).", default=False)


def secured_link(url: str, parsed, insecure: bool, flag: str = "--link", serve: bool = False) -> str:
    """``url`` as the link to a crane is opened: with its SecOC key and the crane's key (``crane_key=``
    public on a laptop, ``signing_key=`` on the crane: ``serve``), or with the explicit opt-out
    (``insecure=1`` added by --insecure-link); a :class:`CliError` (exit 3) for neither, and (exit 2)
    for a key file that cannot be used. A ``twin://`` crane lives on a private in-process bus and
    needs no key."""
    from field.link.link_config import with_insecure

    if parsed.scheme == "twin":
        return url
    opted_out = insecure or parsed.query.get("insecure", "").lower() in ("1", "true", "yes")
    if "secoc_key" not in parsed.query:
        if opted_out:
            return url if "insecure" in parsed.query else with_insecure(url)
        raise CliError(f"{flag} {url} has no SecOC key: without one any node on the bus can forge commands and the "
                       "crane's answers. Add ?secoc_key=KEYFILE (create one with `loggrasp link-key KEYFILE`; the "
                       "crane uses the same file), or opt out explicitly with --insecure-link", EXIT_LINK)
    crane = "signing_key" if serve else "crane_key"
    check_link_keys(parsed, flag, serve)
    if crane in parsed.query:
        return url
    if opted_out:
        return url if "insecure" in parsed.query else with_insecure(url)
    what = ("signing_key=CRANE: the crane signs its answers with it" if serve else
            "crane_key=CRANE.pub: the crane's public key, which tells its answers from a forger's")
    raise CliError(f"{flag} {url} has a SecOC key but no {what} (without it, whoever holds a laptop's key file can "
                   "forge the crane's answers). Create the pair with `loggrasp link-key --crane-signing CRANE` "
                   "(CRANE stays on the crane, CRANE.pub goes to laptops), or opt out explicitly with --insecure-link",
                   EXIT_LINK)


def check_link_keys(parsed, flag: str, serve: bool) -> None:
    """Every key file the link URL names, loaded now: a one-line :class:`CliError` (exit 2) naming
    the file and the URL parameter for a missing, unreadable, open (mode) or wrong key. A laptop
    URL naming the crane's signing key is refused: that key belongs on the crane only."""
    from field.errors import KeyFileError
    from field.link.secoc import load_keys
    from field.link.signing import load_public_key, load_signing_key

    q = parsed.query
    if not serve and "signing_key" in q:
        raise CliError(f"{flag}: signing_key={q['signing_key']} is the crane's signing key; it belongs on the crane "
                       "only - give this laptop crane_key=CRANE.pub (its public key) instead")
    loaders = {"secoc_key": load_keys, "crane_key": load_public_key, "signing_key": load_signing_key}
    for name, load in loaders.items():
        if name in q:
            try:
                load(q[name])
            except KeyFileError as exc:
                raise CliError(f"{flag} {name}=: {exc}") from exc


def link_security_note(url: str, serve: bool = False) -> str | None:
    """The warning a crane link without full authentication gets in the confirmation (None when it
    has its keys): no SecOC key, or (``serve``: the crane's signing key) no crane public key."""
    from field.link.base import LinkURL

    parsed = LinkURL.parse(url)
    if parsed.scheme == "twin":
        return None
    if "secoc_key" not in parsed.query:
        return ("the crane link is NOT authenticated (--insecure-link): any node on the bus could forge this command "
                "or the crane's answers")
    if ("signing_key" if serve else "crane_key") not in parsed.query:
        return ("the crane's answers are NOT signed (--insecure-link): whoever holds a laptop's key file could forge "
                "them")
    return None


def link_key_command(
    path: Path = typer.Argument(None, metavar="[KEYFILE]",
                                help="SecOC key file to create (mode 0600; never overwritten), or to add a key to "
                                     "with --add."),
    add: bool = option("--add", "Add a new key as the next KEY_ID HEX line of an existing KEYFILE (rotation: "
                       "add it on every node, then move it to the first line node by node, then remove the old "
                       "one).", default=False),
    crane_signing: Path = option("--crane-signing", "Also (or only) create the crane's Ed25519 signing key here "
                                 "(mode 0600, for the crane: signing_key=PATH) and its public key at PATH.pub (for "
                                 "every laptop: crane_key=PATH.pub).", default=None, metavar="PATH"),
) -> None:
    """Create the keys of an authenticated crane link: the pre-shared SecOC key (both ends) and
    the crane's signing key pair (the crane signs its answers; laptops hold only its public key,
    so a laptop's key file cannot make crane frames).

    Give the SecOC key to both ends and the crane's keys to each its own, e.g. laptop
    --link 'can://socketcan/can0?secoc_key=K&crane_key=CRANE.pub', crane (crane-sim)
    --link 'can://socketcan/can0?secoc_key=K&signing_key=CRANE'. No key is ever printed.

    \b
    Example: loggrasp link-key ~/.config/loggrasp/crane1.key --crane-signing ~/.config/loggrasp/crane1.sign
    Example: loggrasp link-key ~/.config/loggrasp/crane1.key --add    # a second key line, for rotation
    """
    from field.errors import KeyFileError
    from field.link.secoc import add_key, generate_key_file
    from field.link.signing import generate_signing_key, public_key_path

    if add and path is None:
        raise CliError("--add needs the KEYFILE to add a key to")
    if path is None and crane_signing is None:
        raise CliError("give KEYFILE (a SecOC key) and/or --crane-signing PATH (the crane's signing key pair)")
    o = Output()
    if path is not None and not add:
        if path.exists():
            raise CliError(f"KEYFILE {path} exists; a key is never overwritten - remove it first, choose another "
                           "path, or add a key to it with --add")
        check_output_file(path, "KEYFILE")
    if crane_signing is not None:
        for p in (crane_signing, public_key_path(crane_signing)):
            if p.exists():
                raise CliError(f"--crane-signing: {p} exists; a key is never overwritten - remove it first or choose "
                               "another path")
        check_output_file(crane_signing, "--crane-signing")
    try:
        if path is not None and add:
            key_id = add_key(path)
            o.say(f"added key id {key_id} to {path} (mode 0600); copy the file to every node, then move that line "
                  "first on each")
        elif path is not None:
            o.say(f"wrote a new key to {generate_key_file(path)} (mode 0600); copy it to the crane over a secure "
                  "channel")
        if crane_signing is not None:
            sign, pub = generate_signing_key(crane_signing)
            o.say(f"wrote the crane's signing key to {sign} (mode 0600: it stays on the crane) and its public key to "
                  f"{pub} (for every laptop)")
    except KeyFileError as exc:
        raise CliError(f"{'KEYFILE' if path is not None and str(path) in str(exc) else '--crane-signing'}: {exc}") \
            from exc
