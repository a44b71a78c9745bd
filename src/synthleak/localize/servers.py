"""The study's localization servers: one per (feature tier, server profile, map representation).

``[localize] tiers`` x ``profile`` x ``representation`` (each of the last two a name or a list of names) span the
servers a study attacks (``[localize] servers``, when set, keeps only the ones it names). A server is named after
its tier, with ``@<profile>`` when its profile is not ``strict`` and ``+<representation>`` when its map is not
plain ``points``: ``sift``, ``xfeat@hloc``, ``sift+line-cloud``, ``xfeat@hloc+line-cloud``. The name is the
``tier`` field of every query log and results row, and the folder of its maps and logs. Servers of one tier share
that tier's query features (a profile sets only matching and PnP, a representation only what the map stores).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from synthleak.localize.representations import DEFAULT_REPRESENTATION
from synthleak.localize.tiers import DEFAULT_PROFILE
from synthleak.schema import as_list


@dataclass(frozen=True)
class Server:
    """One server of a study: a tier under a profile, over a map representation."""

    tier: str
    profile: str = DEFAULT_PROFILE
    representation: str = DEFAULT_REPRESENTATION

    @property
    def name(self) -> str:
        """``tier[@profile][+representation]``, the defaults left out."""
        name = self.tier
        if self.profile != DEFAULT_PROFILE:
            name += f"@{self.profile}"
        if self.representation != DEFAULT_REPRESENTATION:
            name += f"+{self.representation}"
        return name

    def localize(self, localize: Any) -> Any:
        """``localize`` (a :class:`~synthleak.config.LocalizeConfig`) as this one server runs it: its single profile
        and representation, and no study-level ``servers`` selection (which servers a study runs is not part of
        any one server's map or cache keys)."""
        return dataclasses.replace(localize, profile=self.profile, representation=self.representation, servers=[])


def study_servers(localize: Any) -> list[Server]:
    """The servers ``localize`` spans: tiers in config order, then profiles, then representations; only those
    ``[localize] servers`` names when it names any."""
    profiles = as_list(localize.profile)
    representations = as_list(localize.representation)
    servers = [Server(tier, profile, representation)
               for tier in localize.tiers for profile in profiles for representation in representations]
    return [server for server in servers if server.name in localize.servers] if localize.servers else servers


def server_by_name(localize: Any) -> dict[str, Server]:
    """:func:`study_servers` by name."""
    return {server.name: server for server in study_servers(localize)}


def base_tier(name: str) -> str:
    """The feature tier of server ``name`` (the part before any ``@`` or ``+``)."""
    return name.split("@", 1)[0].split("+", 1)[0]
