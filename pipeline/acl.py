"""The access control of a pipeline's embedded router (Zenoh ``access_control``): each
stage may put only on its own keys.  Plain data, no zenoh (:mod:`pipeline.transport` hands
it to the router's configuration)."""

from __future__ import annotations

__all__ = ["KEY_ROOT", "STAGE_KEYS", "acl_config"]

#: The first chunk of every key expression of bnptrack (``bnptrack/<run>/<topic>``).
KEY_ROOT = "bnptrack"

#: Keys (relative to ``bnptrack/<run>/``) each stage may put on (and reply from its cache).
STAGE_KEYS: dict[str, tuple[str, ...]] = {
    "source": ("measurements", "truth", "info/source", "eos/source", "health/source", "deadletter",
               "fetch/measurements", "fetch/truth"),
    "tracker": ("tracks", "info/tracker", "eos/tracker", "health/tracker", "deadletter", "fetch/tracks"),
    "sink": ("info/sink", "eos/sink", "health/sink", "deadletter"),
}


def _rule(rule_id: str, messages: list[str], flows: list[str], key_exprs: list[str]) -> dict:
    return {"id": rule_id, "messages": messages, "flows": flows, "permission": "allow", "key_exprs": key_exprs}


def _everyone_rules() -> list[dict]:
    """What every authenticated session may do."""
    return [
        _rule("infrastructure", ["declare_subscriber", "declare_queryable", "query",
                                 "liveliness_query", "declare_liveliness_subscriber"],
              ["ingress", "egress"], ["**", "**/@adv/**"]),
        # the advanced publishers' and subscribers' own detection tokens; a stage's
        # alive/ready tokens only by that stage (below)
        _rule("adv-tokens", ["liveliness_token"], ["ingress", "egress"], ["**/@adv/**"]),
        _rule("see-tokens", ["liveliness_token"], ["egress"], ["**"]),
        _rule("deliver", ["put", "delete", "reply"], ["egress"], ["**", "**/@adv/**"]),
    ]


def _stage_rules(stage: str, topics: tuple[str, ...]) -> list[dict]:
    """What only the user named like ``stage`` may do: put on its topics, hold its tokens."""
    keys = []
    for t in topics:
        keys += [f"{KEY_ROOT}/*/{t}", f"{KEY_ROOT}/*/{t}/**", f"{KEY_ROOT}/*/{t}/@adv/**"]
    return [
        _rule(f"publish-{stage}", ["put", "delete", "reply"], ["ingress"], keys),
        _rule(f"tokens-{stage}", ["liveliness_token"], ["ingress"],
              [f"{KEY_ROOT}/*/{kind}/{stage}" for kind in ("alive", "ready")]),
    ]


def acl_config(stage_keys: dict[str, tuple[str, ...]] | None = None) -> dict:
    """Zenoh ``access_control`` for a pipeline router: default deny; every authenticated
    session may subscribe, query, declare queryables and liveliness tokens, and receive
    data; the user named like a stage may put (and reply to history queries) only on that
    stage's keys in any run (``bnptrack/*/<topic>`` and the advanced publisher's
    ``.../<topic>/@adv/**`` keys: ``**`` does not match a verbatim ``@`` chunk, so those are
    listed explicitly)."""
    stage_keys = STAGE_KEYS if stage_keys is None else stage_keys
    rules = _everyone_rules()
    subjects = [{"id": "anyone"}]
    policies = [{"id": "everyone", "rules": ["infrastructure", "adv-tokens", "see-tokens", "deliver"],
                 "subjects": ["anyone"]}]
    for stage, topics in stage_keys.items():
        rules += _stage_rules(stage, topics)
        subjects.append({"id": f"user-{stage}", "usernames": [stage]})
        policies.append({"id": f"own-keys-{stage}", "rules": [f"publish-{stage}", f"tokens-{stage}"],
                         "subjects": [f"user-{stage}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
