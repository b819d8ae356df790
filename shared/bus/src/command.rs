//! Commands to a process over iceoryx2 request-response: `hydractl swap`
//! asks the supervisor, which answers once the work is done.

use std::fmt::Debug;

use iceoryx2::active_request::ActiveRequest;
use iceoryx2::pending_response::PendingResponse;
use iceoryx2::port::client::Client;
use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;

use crate::{Bus, BusError};

type Factory<Req, Resp> =
    iceoryx2::service::port_factory::request_response::PortFactory<ipc::Service, Req, (), Resp, ()>;

fn open<Req, Resp>(bus: &Bus, name: &str) -> Result<Factory<Req, Resp>, BusError>
where
    Req: ZeroCopySend + Debug + Copy + 'static,
    Resp: ZeroCopySend + Debug + Copy + 'static,
{
    let service_name = ServiceName::new(name).map_err(|e| BusError::ipc(format!("service name {name}"), e))?;
    bus.node()
        .service_builder(&service_name)
        .request_response::<Req, Resp>()
        .open_or_create()
        .map_err(|e| BusError::ipc(format!("opening {name}"), e))
}

/// Takes commands; each is answered when the caller is ready.
pub struct CommandServer<Req, Resp>
where
    Req: ZeroCopySend + Debug + Copy + 'static,
    Resp: ZeroCopySend + Debug + Copy + 'static,
{
    name: String,
    server: Server<ipc::Service, Req, (), Resp, ()>,
}

/// A command received and not yet answered.
pub struct PendingCommand<Req, Resp>
where
    Req: ZeroCopySend + Debug + Copy + 'static,
    Resp: ZeroCopySend + Debug + Copy + 'static,
{
    active: ActiveRequest<ipc::Service, Req, (), Resp, ()>,
}

impl<Req, Resp> CommandServer<Req, Resp>
where
    Req: ZeroCopySend + Debug + Copy + 'static,
    Resp: ZeroCopySend + Debug + Copy + 'static,
{
    pub fn open(bus: &Bus, name: &str) -> Result<Self, BusError> {
        let server = open::<Req, Resp>(bus, name)?
            .server_builder()
            .create()
            .map_err(|e| BusError::ipc(format!("server on {name}"), e))?;
        Ok(Self {
            name: name.to_owned(),
            server,
        })
    }

    /// The next waiting command, if any.
    pub fn receive(&self) -> Result<Option<PendingCommand<Req, Resp>>, BusError> {
        self.server
            .receive()
            .map(|active| active.map(|active| PendingCommand { active }))
            .map_err(|e| BusError::ipc(format!("receive on {}", self.name), e))
    }
}

impl<Req, Resp> PendingCommand<Req, Resp>
where
    Req: ZeroCopySend + Debug + Copy + 'static,
    Resp: ZeroCopySend + Debug + Copy + 'static,
{
    pub fn request(&self) -> Req {
        *self.active.payload()
    }

    /// Answers; a caller that gave up waiting is not an error of ours.
    pub fn reply(self, response: Resp) -> Result<(), BusError> {
        if !self.active.is_connected() {
            return Ok(());
        }
        self.active
            .send_copy(response)
            .map_err(|e| BusError::ipc("sending a reply", e))
    }
}

/// Sends commands and waits for their answers.
pub struct CommandClient<Req, Resp>
where
    Req: ZeroCopySend + Debug + Copy + 'static,
    Resp: ZeroCopySend + Debug + Copy + 'static,
{
    name: String,
    client: Client<ipc::Service, Req, (), Resp, ()>,
}

/// A command sent, its answer not yet received.
pub struct PendingReply<Req, Resp>
where
    Req: ZeroCopySend + Debug + Copy + 'static,
    Resp: ZeroCopySend + Debug + Copy + 'static,
{
    pending: PendingResponse<ipc::Service, Req, (), Resp, ()>,
}

impl<Req, Resp> CommandClient<Req, Resp>
where
    Req: ZeroCopySend + Debug + Copy + 'static,
    Resp: ZeroCopySend + Debug + Copy + 'static,
{
    pub fn open(bus: &Bus, name: &str) -> Result<Self, BusError> {
        let client = open::<Req, Resp>(bus, name)?
            .client_builder()
            .create()
            .map_err(|e| BusError::ipc(format!("client on {name}"), e))?;
        Ok(Self {
            name: name.to_owned(),
            client,
        })
    }

    pub fn send(&self, request: Req) -> Result<PendingReply<Req, Resp>, BusError> {
        let pending = self
            .client
            .send_copy(request)
            .map_err(|e| BusError::ipc(format!("sending on {}", self.name), e))?;
        Ok(PendingReply { pending })
    }
}

impl<Req, Resp> PendingReply<Req, Resp>
where
    Req: ZeroCopySend + Debug + Copy + 'static,
    Resp: ZeroCopySend + Debug + Copy + 'static,
{
    /// How many servers got the command: 0 when nobody is listening.
    pub fn servers(&self) -> usize {
        self.pending.number_of_server_connections()
    }

    pub fn try_receive(&self) -> Result<Option<Resp>, BusError> {
        self.pending
            .receive()
            .map(|r| r.map(|r| *r.payload()))
            .map_err(|e| BusError::ipc("receiving a reply", e))
    }
}
