//! The keys of a health report's `detail`: named once, for the services that write them and
//! the programs that read them (`docs/protocol.md`, "Health").

/// The keys of a health report's `detail` (docs/protocol.md, "Health"): each service's own
/// figures, named once here for the services that write them and the programs that read them.
/// (Refusals are counted under `rejected.<reason>`, the reasons being the decoders'.)
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Detail {
    /// capture: what it reads from.
    Source,
    /// moments: the frame threshold, objects tracked, blobs ignored in masked places, and
    /// windowed steps the cores settled or widened.
    Threshold,
    Tracked,
    Masked,
    CoresSettled,
    CoresWidened,
    /// fusion: cameras heard recently, objects followed, observations late for their set or
    /// before the start, recorded sets formed short, and blobs left out (outside the volume,
    /// hiding another, cut by an edge, out of line by area, seen by one camera only, points
    /// seen by too few cameras to start an object, merged).
    CamerasLive,
    Objects,
    Late,
    BeforeStart,
    ShortSets,
    OutsideVolume,
    Hiding,
    Clipped,
    AreaMismatch,
    SingleViewUnmatched,
    TooFewViews,
    MergedBlobs,
    /// Any service that names what it lost last (`cam0 frames 212–213`).
    LastLost,
    /// serial: the port (`open`/`closed`), packets whose values were clamped to the packet.
    Port,
    Clamped,
    /// recorder: observations written.
    Observations,
    /// vrfeed: VRPN clients, the VRPN port's state, failed UDP sends, latency percentiles.
    VrpnClients,
    Vrpn,
    SendErrors,
    LatencyP50Us,
    LatencyP99Us,
    /// vrfeed: each lab protocol's state (`listening`, `port in use`) and its clients.
    Natnet,
    NatnetClients,
    Qualisys,
    QualisysClients,
    Ros2,
    Lsl,
    LslConsumers,
    /// viewer: browsers connected now and since start, sockets refused, bad requests, bytes
    /// sent, previews forwarded, the page's address.
    Clients,
    Connections,
    Refused,
    BadRequests,
    SentBytes,
    Previews,
    Url,
    /// router: the endpoints it listens on, and the routers of other PCs linked to it.
    Listen,
    Routers,
    /// Any service: liveliness tokens declared anew when a launcher found one missing at its
    /// router (`TokenRenewal`).
    TokenRenewals,
    /// fusion: the bodies it follows, and the changes of the rig file's bodies and models it
    /// applied while running.
    Bodies,
    RigReloads,
}

impl Detail {
    /// The key as it appears in the report.
    pub const fn key(self) -> &'static str {
        match self {
            Detail::Source => "source",
            Detail::Threshold => "threshold",
            Detail::Tracked => "tracked",
            Detail::Masked => "masked",
            Detail::CoresSettled => "cores_settled",
            Detail::CoresWidened => "cores_widened",
            Detail::CamerasLive => "cameras_live",
            Detail::Objects => "objects",
            Detail::Late => "late",
            Detail::BeforeStart => "before_start",
            Detail::ShortSets => "short_sets",
            Detail::OutsideVolume => "outside_volume",
            Detail::Hiding => "hiding",
            Detail::Clipped => "clipped",
            Detail::AreaMismatch => "area_mismatch",
            Detail::SingleViewUnmatched => "single_view_unmatched",
            Detail::TooFewViews => "too_few_views",
            Detail::MergedBlobs => "merged_blobs",
            Detail::LastLost => "last_lost",
            Detail::Port => "port",
            Detail::Clamped => "clamped",
            Detail::Observations => "observations",
            Detail::VrpnClients => "vrpn_clients",
            Detail::Vrpn => "vrpn",
            Detail::SendErrors => "send_errors",
            Detail::LatencyP50Us => "latency_p50_us",
            Detail::LatencyP99Us => "latency_p99_us",
            Detail::Natnet => "natnet",
            Detail::NatnetClients => "natnet_clients",
            Detail::Qualisys => "qualisys",
            Detail::QualisysClients => "qualisys_clients",
            Detail::Ros2 => "ros2",
            Detail::Lsl => "lsl",
            Detail::LslConsumers => "lsl_consumers",
            Detail::Clients => "clients",
            Detail::Connections => "connections",
            Detail::Refused => "refused",
            Detail::BadRequests => "bad_requests",
            Detail::SentBytes => "sent_bytes",
            Detail::Previews => "previews",
            Detail::Url => "url",
            Detail::Listen => "listen",
            Detail::Routers => "routers",
            Detail::TokenRenewals => "token_renewals",
            Detail::Bodies => "bodies",
            Detail::RigReloads => "rig_reloads",
        }
    }
}
