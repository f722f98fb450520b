// Virtual VDA 5050 2.0.0 AGVs of the npm package vda-5050-lib (Siemens AG, MIT licence; an
// implementation fleetgate did not write, installed outside the project: see
// docs/vda5050.md). Usage: node external_agvs.js BROKER_URL SPEC_JSON, where SPEC_JSON is
// {"interface": "uagv", "vehicles": [{"manufacturer", "serial", "mapId", "x", "y", "theta",
// "speed"}]}. Prints "ready" once every AGV is connected; stops them on SIGTERM.
const { AgvController, VirtualAgvAdapter } = require("vda-5050-lib");

async function main() {
    const [broker, specJson] = process.argv.slice(2);
    const spec = JSON.parse(specJson);
    const agvs = [];
    for (const v of spec.vehicles) {
        const agv = new AgvController(
            { manufacturer: v.manufacturer, serialNumber: v.serial },
            { interfaceName: spec.interface, transport: { brokerUrl: broker }, vdaVersion: "2.0.0" },
            { agvAdapterType: VirtualAgvAdapter },
            {
                initialPosition: { mapId: v.mapId, x: v.x, y: v.y, theta: v.theta, lastNodeId: "" },
                vehicleSpeed: v.speed,
            });
        await agv.start();
        agvs.push(agv);
    }
    console.log("ready");
    process.on("SIGTERM", async () => {
        for (const agv of agvs) {
            await agv.stop();
        }
        process.exit(0);
    });
}

main().catch((err) => {
    console.error(String(err));
    process.exit(1);
});
